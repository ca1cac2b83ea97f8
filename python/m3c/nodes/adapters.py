"""Adapters between the perception/VO nodes and the components that implement them.

Each node of the frame, patch and SMPL levels that needs a learned or external component calls it through one
adapter here, with the data contract of m3c.nodes.records. An adapter is an entry in COMPONENTS; `connect`
points it at an implementation:

    from m3c.nodes import adapters
    adapters.connect("detections", my_detector)   # my_detector(ctx, inputs, options) -> {"frame", "box", "score"}

Until an implementation is connected, a node that needs it fails before anything runs with a message naming the
component, so M3C never produces results from a component it does not have.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from m3c.pipeline import ComponentUnavailable


@dataclass
class Component:
    name: str
    what: str  # the capability, for messages
    module: str  # where its implementation lives
    signature: str  # the call and its result (the data contract)
    implementation: Callable | None = None
    hint: str = ""  # what the user can do meanwhile

    def require(self, node: str) -> Callable:
        if self.implementation is None:
            fix = f"{self.module} is not part of this build yet"
            raise ComponentUnavailable(node, self.what, fix + (f"; {self.hint}" if self.hint else ""))
        return self.implementation


COMPONENTS: dict[str, Component] = {c.name: c for c in [
    Component("detections", "person detection", "m3c.perception (MediaPipe)",
              "(ctx, {video}, options) -> {frame (N,), box (N, 4), score (N,)}"),
    Component("masks", "person segmentation", "m3c.perception (MediaPipe)",
              "(ctx, {video, detections}, options) -> encode_masks([...]) with one mask per detection"),
    Component("depth", "monocular depth", "a depth backend",
              "(ctx, {video}, options) -> {depth: (T, h, w) float32 relative depth, scale_to_image: (2,)}",
              hint="set depth.enabled: false (the default) to run visual odometry without depth"),
    Component("keypoints", "2D keypoints (COCO-17)", "m3c.perception (MediaPipe pose)",
              "(ctx, {patches, boxes, detections}, options) -> {keypoints (N, 17, 3)}"),
    Component("body", "camera-local body fitting", "m3c.perception (per-frame body fitting)",
              "(ctx, {patches, boxes, keypoints, camera, detections}, options) -> {pose (N, 24, 3), "
              "betas (N, B), transl (N, 3) or crop_cam (N, 3)}"),
    Component("tracking", "multi-person tracking", "m3c.perception (tracking)",
              "(ctx, {detections, keypoints, body}, options) -> {track_id (N,)}"),
    Component("contacts", "foot contact estimation", "m3c.perception (contacts)",
              "(ctx, {detections, keypoints, body, video}, options) -> {joint_contacts (N, 4)}"),
    Component("vo", "visual odometry for a moving camera", "m3c.vo (patch visual odometry)",
              "(ctx, {video, masks, depth, camera}, options) -> {world_from_cam (T, 4, 4)}",
              hint="for a camera that does not move, pass --static-camera (vo.static: true)"),
]}


def connect(name: str, implementation: Callable | None) -> None:
    """Points adapter `name` at `implementation` (None disconnects it)."""
    if name not in COMPONENTS:
        raise KeyError(f"no adapter {name!r}; adapters: {sorted(COMPONENTS)}")
    COMPONENTS[name].implementation = implementation


def require(name: str, node: str) -> Callable:
    return COMPONENTS[name].require(node)
