"""Perception and odometry nodes (thesis levels 1-3): each validates the data contract of m3c.nodes.records
around a component reached through m3c.nodes.adapters."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from m3c.nodes import adapters
from m3c.nodes.records import table_length
from m3c.pipeline import Node, PipelineError, register_node


@dataclass
class BackendConfig:
    backend: str = "default"
    options: dict[str, Any] = field(default_factory=dict)


class AdapterNode(Node):
    """A node whose work is done by adapter `component`; `validate` checks what comes back."""

    component = ""
    Config = BackendConfig

    def check(self, ctx) -> None:
        adapters.require(self.component, self.name)

    def run(self, ctx, inputs):
        implementation = adapters.require(self.component, self.name)
        result = implementation(ctx, inputs, dict(self.config.options, backend=self.config.backend))
        if not isinstance(result, dict):
            raise PipelineError(f"node {self.name!r}: the {self.component} component returned "
                                f"{type(result).__name__}, expected a dict")
        return {self.outputs[0]: self.validate(inputs, result)}

    def validate(self, inputs, result: dict) -> dict:
        return result


def _num_detections(inputs) -> int:
    return table_length(inputs["detections"], ("frame",), "detections")


def _check_rows(node: str, result: dict, columns: dict[str, tuple], n: int) -> dict:
    """Each column must be an array of shape (n, *trailing) (None in trailing = any size)."""
    out = dict(result)
    for column, trailing in columns.items():
        if column not in result:
            continue
        array = np.asarray(result[column])
        ok = array.ndim == 1 + len(trailing) and array.shape[0] == n and all(
            t is None or t == s for t, s in zip(trailing, array.shape[1:]))
        if not ok:
            raise PipelineError(f"node {node!r}: {column} must have shape ({n}, {', '.join(map(str, trailing))}) "
                                f"(one row per detection), got {array.shape}")
        out[column] = array
    return out


@register_node
class DetectionsNode(AdapterNode):
    type_name = "detections"
    level = "frame"
    component = "detections"
    inputs = ("video",)
    outputs = ("detections",)

    def validate(self, inputs, result):
        n = table_length(result, ("frame", "box", "score"), f"node {self.name!r}")
        result = _check_rows(self.name, result, {"frame": (), "box": (4,), "score": ()}, n)
        frames = result["frame"].astype(np.int64)
        if n and (frames.min() < 0 or frames.max() >= inputs["video"]["num_frames"]):
            raise PipelineError(f"node {self.name!r}: detection frame indices must lie in 0 .. T-1")
        order = np.lexsort((-result["score"], frames))  # by frame, best first: a stable layout for caching
        return {"frame": frames[order], "box": result["box"][order].astype(np.float32),
                "score": result["score"][order].astype(np.float32)}


@register_node
class MasksNode(AdapterNode):
    type_name = "masks"
    level = "frame"
    component = "masks"
    inputs = ("video", "detections")
    outputs = ("masks",)

    def validate(self, inputs, result):
        n = _num_detections(inputs)
        if len(result.get("offsets", [])) != n + 1 or len(result.get("regions", [])) != n:
            raise PipelineError(f"node {self.name!r}: expected one mask per detection ({n}), built with "
                                "m3c.nodes.records.encode_masks")
        return result


@register_node
class DepthNode(AdapterNode):
    """Relative depth per frame, used to initialise visual odometry. Off by default (thesis: optional)."""

    type_name = "depth"
    level = "frame"
    component = "depth"
    inputs = ("video",)
    outputs = ("depth",)

    @dataclass
    class Config(BackendConfig):
        enabled: bool = False

    def check(self, ctx) -> None:
        if self.config.enabled:
            super().check(ctx)

    def run(self, ctx, inputs):
        if not self.config.enabled:
            return {"depth": {"available": False}}
        out = super().run(ctx, inputs)
        out["depth"]["available"] = True
        return out


@register_node
class KeypointsNode(AdapterNode):
    type_name = "keypoints"
    level = "patch"
    component = "keypoints"
    inputs = ("detections", "boxes", "patches")
    outputs = ("keypoints",)

    def validate(self, inputs, result):
        n = _num_detections(inputs)
        out = _check_rows(self.name, result, {"keypoints": (17, 3)}, n)
        if "keypoints" not in out:
            raise PipelineError(f"node {self.name!r}: the keypoints component returned no 'keypoints'")
        return {"keypoints": out["keypoints"].astype(np.float32)}


@register_node
class BodyNode(AdapterNode):
    """Camera-local body per detection: pose, betas and a camera (full-image translation or crop camera)."""

    type_name = "body"
    level = "patch"
    component = "body"
    inputs = ("detections", "boxes", "patches", "keypoints", "camera")
    optional_inputs = ("keypoints",)
    outputs = ("body",)
    settings = ("body_model",)

    def validate(self, inputs, result):
        n = _num_detections(inputs)
        out = _check_rows(self.name, result, {"pose": (24, 3), "betas": (None,), "transl": (3,),
                                              "crop_cam": (3,)}, n)
        if "pose" not in out or "betas" not in out or not ({"transl", "crop_cam"} & set(out)):
            raise PipelineError(f"node {self.name!r}: the body component must return pose, betas and transl or "
                                "crop_cam")
        return {k: np.asarray(v, dtype=np.float64) if isinstance(v, np.ndarray) else v for k, v in out.items()}


@register_node
class TrackingNode(AdapterNode):
    type_name = "tracking"
    level = "smpl"
    component = "tracking"
    inputs = ("detections", "keypoints", "body")
    outputs = ("tracking",)

    def validate(self, inputs, result):
        n = _num_detections(inputs)
        out = _check_rows(self.name, result, {"track_id": ()}, n)
        if "track_id" not in out:
            raise PipelineError(f"node {self.name!r}: the tracking component returned no 'track_id'")
        return {"track_id": out["track_id"].astype(np.int64)}


@register_node
class ContactsNode(AdapterNode):
    type_name = "contacts"
    level = "smpl"
    component = "contacts"
    inputs = ("video", "detections", "keypoints", "body")
    outputs = ("contacts",)

    def validate(self, inputs, result):
        n = _num_detections(inputs)
        out = _check_rows(self.name, result, {"joint_contacts": (4,)}, n)
        if "joint_contacts" not in out:
            raise PipelineError(f"node {self.name!r}: the contacts component returned no 'joint_contacts'")
        return {"joint_contacts": np.clip(out["joint_contacts"], 0, 1).astype(np.float32)}


@register_node
class VisualOdometryNode(AdapterNode):
    """Camera poses world_from_cam (T, 4, 4); the world is the first camera's frame, translation up to scale.
    With static: true the camera is taken not to move (identity poses) and no odometry runs."""

    type_name = "vo"
    level = "patch"
    component = "vo"
    inputs = ("video", "masks", "depth", "camera")
    optional_inputs = ("masks", "depth")
    outputs = ("cameras",)

    @dataclass
    class Config(BackendConfig):
        static: bool = False

    def check(self, ctx) -> None:
        if not self.config.static:
            super().check(ctx)

    def run(self, ctx, inputs):
        T = int(inputs["video"]["num_frames"])
        if self.config.static:
            return {"cameras": {"world_from_cam": np.tile(np.eye(4), (T, 1, 1)), "static": True,
                                "source": "static camera (declared)"}}
        out = super().run(ctx, inputs)["cameras"]
        poses = np.asarray(out.get("world_from_cam"), dtype=np.float64)
        if poses.shape != (T, 4, 4) or not np.isfinite(poses).all():
            raise PipelineError(f"node {self.name!r}: world_from_cam must be ({T}, 4, 4) and finite, got "
                                f"{poses.shape}")
        return {"cameras": {"world_from_cam": poses, "static": False,
                            "source": str(out.get("source", self.config.backend))}}
