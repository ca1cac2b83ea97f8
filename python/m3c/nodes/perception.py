"""Perception and odometry nodes (thesis levels 1-3).

The default graph runs M3C's perception (m3c.perception) as one `perception` node and its patch visual odometry
(m3c.vo) in the `vo` node. The per-task node types below it (detections, masks, keypoints, body, tracking,
contacts) hold the same data contract (m3c.nodes.records) for graphs that take each task from a separate
component, reached through m3c.nodes.adapters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from m3c.nodes import adapters
from m3c.nodes.frames import stream_frames
from m3c.nodes.records import encode_packed_masks, people_mask, rows_by_frame, table_length
from m3c.pipeline import ComponentUnavailable, InputError, Node, PipelineError, register_node
from m3c.vo.scale import MAX_WANDER, MIN_BASELINE, translation_baseline, turns_in_place


@register_node
class PerceptionNode(Node):
    """People in every frame, in one streaming pass (m3c.perception.run_perception_frames): detection (with the
    tracker's predicted boxes as proposals between detector runs), segmentation, the thesis's isolated square
    patches (5 px padding, shifted inside the frame, other people whitened), 2D keypoints, appearance-aware
    tracking; then per track the camera-local body fit (warm-started frame to frame) and contacts.

    One node rather than one per task because the tasks feed each other within a frame: the tracker's
    predictions are the detector's proposals, and each person's patch is isolated from everyone found in the
    frame. Outputs are the per-detection tables of m3c.nodes.records, one row per tracked person per frame
    (people of unconfirmed tracks and frames whose body fit failed are left out).

    Config: estimators (task -> name or {name, options}; m3c.perception.available(task) lists them),
    static_camera (contacts from foot speeds in the camera frame), and any other m3c.perception.PerceptionConfig
    setting under `options` (tracker, detect_every, ...).

    The thesis's networks: 2D pose and body left unnamed become `vitpose` and `hmr2` when their official
    checkpoints lie in the models folder (--checkpoints / settings.models_dir / $M3C_MODELS, at
    NETWORK_CHECKPOINTS' paths); named without a `checkpoint` option, they read it from there. The resolved names
    are written into the node's config, so the cache key and results.json record which backend ran.
    """

    type_name = "perception"
    level = "patch"
    inputs = ("video", "camera")
    outputs = ("detections", "masks", "keypoints", "body", "tracking", "contacts")
    settings = ("body_model", "models_dir")
    # 2: the body fit retries a drifting warm start cold without its velocity prediction (cpp/fit)
    # 3: the tracker keeps recent poses and locations, gates on colour, matches tentative tracks last; track
    #    splits are merged; the detector searches smaller tiles every 15 frames
    version = "3"

    def _network_checkpoints(self, ctx) -> dict:
        """task -> (estimator name, checkpoint path in the models folder or None)."""
        from m3c.models.hmr2 import HMR2_SOURCE
        from m3c.models.vitpose import VITPOSE_SOURCE

        folder = ctx.models_dir()
        out = {}
        for task, name, source in (("pose2d", "vitpose", VITPOSE_SOURCE), ("body", "hmr2", HMR2_SOURCE)):
            out[task] = (name, None if folder is None else folder / source.default_path, source)
        return out

    def _resolve_networks(self, ctx) -> None:
        """Picks the networks whose checkpoints are present for tasks left unnamed, and gives named network
        estimators their checkpoint from the models folder."""
        estimators = self.config.estimators
        for task, (name, path, _) in self._network_checkpoints(ctx).items():
            spec = estimators.get(task)
            if spec is None:
                if path is not None and path.is_file():
                    estimators[task] = {"name": name, "options": {"checkpoint": str(path)}}
                continue
            spec = {"name": spec, "options": {}} if isinstance(spec, str) else spec
            options = spec.get("options") or {} if isinstance(spec, dict) else {}
            if isinstance(spec, dict) and spec.get("name") == name and "checkpoint" not in options and path:
                estimators[task] = {"name": name, "options": {**options, "checkpoint": str(path)}}

    def key_config(self, ctx):
        from m3c.pipeline.cache import file_digest

        self._resolve_networks(ctx)
        config = super().key_config(ctx)
        digests = {}
        for task, spec in self.config.estimators.items():
            options = spec.get("options") or {} if isinstance(spec, dict) else {}
            path = options.get("checkpoint")
            if path and Path(path).is_file():
                digests[task] = file_digest(path)
        if digests:
            config["checkpoint_digests"] = digests
        return config

    @dataclass
    class Config:
        estimators: dict[str, Any] = field(default_factory=dict)
        static_camera: bool = False
        options: dict[str, Any] = field(default_factory=dict)

    def _perception_config(self, intrinsics=None, body_model: str | None = None):
        from m3c.perception import PerceptionConfig

        data = {**self.config.options, **self.config.estimators, "static_camera": self.config.static_camera}
        if intrinsics is not None:
            data["intrinsics"] = [float(v) for v in intrinsics]
        try:
            config = PerceptionConfig.from_dict(data)
        except (TypeError, ValueError) as err:
            raise InputError(f"node {self.name!r}: {err}") from None
        body = config.estimators["body"]
        if body.name in ("fit", "hmr2") and body_model is not None and "model_path" not in body.options:
            body.options["model_path"] = body_model  # fit with the run's body model
        return config

    def check(self, ctx) -> None:
        from m3c.models.checkpoint import CheckpointNotFoundError, resolve_path
        from m3c.perception.mediapipe_pose import NAME, mediapipe_available

        from m3c.perception import available

        self._resolve_networks(ctx)
        config = self._perception_config()
        for task, spec in config.estimators.items():
            if spec.name not in available(task):
                raise InputError(f"node {self.name!r}: no {task} estimator named {spec.name!r}; available: "
                                 f"{', '.join(available(task))}")
        for task, (name, _, source) in self._network_checkpoints(ctx).items():
            spec = config.estimators[task]
            if spec.name == name:
                try:
                    resolve_path(spec.options.get("checkpoint"), source)
                except CheckpointNotFoundError as err:
                    raise ComponentUnavailable(self.name, f"{source.model}'s checkpoint (the {task} estimator)",
                                               str(err)) from None
        users = sorted(task for task, spec in config.estimators.items() if spec.name == NAME)
        if users and not mediapipe_available():
            raise ComponentUnavailable(self.name, f"MediaPipe (the {', '.join(users)} estimator)",
                                       "install it with pip install 'm3c[perception]' (mediapipe==0.10.14, "
                                       "its pose models ship inside the wheel)")

    def run(self, ctx, inputs):
        import cv2

        from m3c.perception import run_perception_frames

        video = inputs["video"]
        self._resolve_networks(ctx)
        config = self._perception_config(inputs["camera"]["intrinsics"], ctx.settings.body_model)
        ctx.log.info("estimators: %s", ", ".join(f"{t} {s.name}" for t, s in config.estimators.items()))
        T = int(video["num_frames"])
        with ctx.progress("people", T) as bar:
            frames = (cv2.cvtColor(frame, cv2.COLOR_BGR2RGB) for _, frame in stream_frames(ctx, video))
            result = run_perception_frames(frames, float(video["fps"]), (video["height"], video["width"]), config,
                                           progress=lambda _: bar.update(), source=video["name"])
        if result.num_frames != T:
            raise InputError(f"{video['name']}: decoded {result.num_frames} of {T} frames")
        ctx.log.info("%d track(s); seconds per stage: %s", len(result.tracks),
                     ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items() if v >= 0.05))
        if result.merged:
            ctx.log.info("merged track splits (id -> id kept): %s",
                         ", ".join(f"{k} -> {v}" for k, v in sorted(result.merged.items())))
        seen = int(np.count_nonzero(result.people_per_frame))
        if not result.tracks and seen:
            # People were seen, too briefly for the tracker to confirm anyone: say so, not "no detections".
            raise InputError(f"people were seen in only {seen} of {T} frame(s), too few for a person track (the "
                             f"tracker confirms a person after {config.tracker.min_hits} detections); M3C needs a "
                             "person visible over several frames")
        return self._tables(result)

    @staticmethod
    def _tables(result) -> dict:
        rows: dict[str, list] = {k: [] for k in ("frame", "box", "score", "keypoints", "pose", "betas", "transl",
                                                 "track_id", "contacts", "mask")}
        for track in result.tracks:
            valid = track.bodies.valid
            pose = track.bodies.pose
            for i in np.flatnonzero(valid):
                rows["frame"].append(track.frame_ids[i])
                rows["box"].append(track.boxes[i])
                rows["score"].append(track.scores[i])
                rows["keypoints"].append(track.keypoints[i, :17])
                rows["pose"].append(pose[i])
                rows["betas"].append(track.bodies.betas[i])
                rows["transl"].append(track.bodies.transl[i])
                rows["track_id"].append(track.track_id)
                rows["contacts"].append(track.contacts[i])
                mask = track.masks[i] if track.masks is not None else None
                if mask is None:
                    rows["mask"].append((np.zeros(0, np.uint8), 0, 0, 0, 0))
                else:
                    (bits, h, w), box = mask
                    rows["mask"].append((bits, h, w, int(box[0]), int(box[1])))
        n = len(rows["frame"])
        order = np.lexsort((-np.asarray(rows["score"], dtype=np.float64).reshape(n),
                            np.asarray(rows["frame"], dtype=np.int64).reshape(n)))

        def column(name, dtype, trailing):
            return np.asarray(rows[name], dtype=dtype).reshape((n,) + trailing)[order]

        num_betas = len(result.tracks[0].bodies.betas[0]) if result.tracks else 10
        return {
            "detections": {"frame": column("frame", np.int64, ()), "box": column("box", np.float32, (4,)),
                           "score": column("score", np.float32, ())},
            "masks": encode_packed_masks([rows["mask"][k] for k in order]),
            "keypoints": {"keypoints": column("keypoints", np.float32, (17, 3))},
            "body": {"pose": column("pose", np.float64, (24, 3)), "betas": column("betas", np.float64, (num_betas,)),
                     "transl": column("transl", np.float64, (3,))},
            "tracking": {"track_id": column("track_id", np.int64, ())},
            "contacts": {"joint_contacts": column("contacts", np.float32, (4,))},
        }


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

    backend "patch" (default): M3C's patch visual odometry (m3c.vo), streaming the frames, with every person's
    mask (from the masks and detections inputs) hidden from it, and depth maps when the depth node gives them;
    options: m3c.vo.VOConfig settings. Its front-end (method): "lk" Lucas-Kanade, "dpvo" DPVO's networks
    (m3c.vo.dpvo, the official dpvo.pth from `checkpoint` or the models folder), "auto" dpvo when that file is
    there. Any other backend goes through the "vo" adapter. Output cameras: world_from_cam (T, 4, 4), static,
    source, and points (M, 3) the odometry's map when it gives one; rotation_only when the camera turned in place
    (m3c.vo.scale.turns_in_place: translations zeroed). With static: true
    the camera is taken not to move (identity poses) and no odometry runs."""

    type_name = "vo"
    level = "patch"
    component = "vo"
    inputs = ("video", "masks", "detections", "depth", "camera")
    optional_inputs = ("masks", "detections", "depth")
    outputs = ("cameras",)
    settings = ("models_dir",)

    @dataclass
    class Config(BackendConfig):
        backend: str = "patch"
        static: bool = False
        method: str = "auto"  # front-end of the patch backend: auto, lk or dpvo
        checkpoint: str | None = None  # dpvo.pth; None = $M3C_MODELS/dpvo/dpvo.pth (or --checkpoints DIR)
        dpvo_iterations: int = 2  # update-operator steps per measurement
        # A camera whose translation spans under min_baseline of the scene's depth and wanders over a path more than
        # max_wander times that span turns in place (m3c.vo.scale.turns_in_place): its position is held fixed.
        min_baseline: float = MIN_BASELINE
        max_wander: float = MAX_WANDER

    def _dpvo_checkpoint(self, ctx):
        """The DPVO file the run uses, or None (method lk, or auto without the file)."""
        from m3c.models.checkpoint import locate
        from m3c.models.dpvo import DPVO_SOURCE

        if self.config.static or self.config.backend != "patch" or self.config.method == "lk":
            return None
        return locate(self.config.checkpoint, ctx.models_dir(), DPVO_SOURCE, self.config.method == "dpvo")

    def key_config(self, ctx):
        from m3c.models.checkpoint import CheckpointNotFoundError
        from m3c.pipeline.cache import file_digest

        try:
            path = self._dpvo_checkpoint(ctx)
        except CheckpointNotFoundError:  # method dpvo without its file: check() reports it
            path = None
        if self.config.method == "auto" and not self.config.static and self.config.backend == "patch":
            # Resolved once, so the key and results.json name the front-end that runs.
            self.config.method = "dpvo" if path is not None else "lk"
        config = super().key_config(ctx)
        config["dpvo_digest"] = file_digest(path) if path is not None else None
        return config

    def check(self, ctx) -> None:
        from m3c.models.checkpoint import CheckpointNotFoundError

        if self.config.static:
            return
        if self.config.method not in ("auto", "lk", "dpvo"):
            raise InputError(f"node {self.name!r}: method must be auto, lk or dpvo, got {self.config.method!r}")
        if self.config.backend == "patch":
            self._vo_config()
            try:
                self._dpvo_checkpoint(ctx)
            except CheckpointNotFoundError as err:
                raise ComponentUnavailable(self.name, "DPVO's checkpoint", str(err)) from None
        else:
            super().check(ctx)

    def load(self, ctx) -> None:
        self._dpvo = None
        path = self._dpvo_checkpoint(ctx)
        if path is not None:
            from m3c.models.dpvo import load_dpvo

            self._dpvo = load_dpvo(path)
            ctx.log.info("visual odometry with DPVO's networks from %s", path)

    def unload(self) -> None:
        self._dpvo = None

    def _vo_config(self):
        from m3c.vo import VOConfig

        try:
            return VOConfig(**self.config.options)
        except (TypeError, ValueError) as err:
            raise InputError(f"node {self.name!r}: bad option in vo.options ({err}); options are m3c.vo.VOConfig "
                             "settings") from None

    def run(self, ctx, inputs):
        T = int(inputs["video"]["num_frames"])
        if not (self.config.min_baseline >= 0 and self.config.max_wander >= 1):
            raise InputError(f"vo.min_baseline must be >= 0 and vo.max_wander >= 1, got {self.config.min_baseline} "
                             f"and {self.config.max_wander}")
        if self.config.static:
            return {"cameras": {"world_from_cam": np.tile(np.eye(4), (T, 1, 1)), "static": True,
                                "source": "static camera (declared)"}}
        if self.config.backend == "patch":
            out = self._patch_vo(ctx, inputs)
        else:
            out = super().run(ctx, inputs)["cameras"]
        poses = np.asarray(out.get("world_from_cam"), dtype=np.float64)
        if poses.shape != (T, 4, 4) or not np.isfinite(poses).all():
            raise PipelineError(f"node {self.name!r}: world_from_cam must be ({T}, 4, 4) and finite, got "
                                f"{poses.shape}")
        cameras = {"world_from_cam": poses, "static": False, "source": str(out.get("source", self.config.backend))}
        points = np.asarray(out.get("points", np.zeros((0, 3))), dtype=np.float32).reshape(-1, 3)
        if np.isfinite(points).all():
            cameras["points"] = points  # the odometry's map (world, VO units), for the scale against the ground
            if turns_in_place(poses, points, self.config.min_baseline, self.config.max_wander):
                extent, wander = translation_baseline(poses, points)
                ctx.log.warning("the camera turned in place: its odometry translation spans %.1f%% of the scene's "
                                "depth (under vo.min_baseline, %.0f%%) and wanders over a path %.1fx that (over "
                                "vo.max_wander, %.1f), so its position is held fixed (--set vo.min_baseline=0 keeps "
                                "the translation)", 100 * extent, 100 * self.config.min_baseline, wander,
                                self.config.max_wander)
                cameras["world_from_cam"] = poses.copy()
                cameras["world_from_cam"][:, :3, 3] = 0.0
                cameras["rotation_only"] = True
        return {"cameras": cameras}

    def _patch_vo(self, ctx, inputs) -> dict:
        from m3c.vo import VisualOdometry

        video, masks, detections = inputs["video"], inputs["masks"], inputs["detections"]
        if (masks is None) != (detections is None):
            raise PipelineError(f"node {self.name!r}: wire both masks and detections (to hide people from the "
                                "odometry) or neither")
        rows_of_frame = rows_by_frame(detections) if masks is not None else {}
        depth = inputs["depth"]
        maps = depth.get("depth") if depth is not None and depth.get("available") else None
        height, width = int(video["height"]), int(video["width"])
        network = getattr(self, "_dpvo", None)
        front_end = None
        if network is not None:
            from m3c.vo.dpvo import DPVOFrontEnd

            front_end = DPVOFrontEnd(network, iterations=self.config.dpvo_iterations)
        vo = VisualOdometry(intrinsics=inputs["camera"]["intrinsics"], config=self._vo_config(), bgr=True,
                            front_end=front_end)
        with ctx.progress("camera", int(video["num_frames"])) as bar:
            for i, frame in stream_frames(ctx, video):
                mask = None if masks is None else people_mask(masks, rows_of_frame.get(i, []), width, height)
                frame_depth = None
                if maps is not None:
                    import cv2

                    frame_depth = cv2.resize(np.asarray(maps[i], dtype=np.float32), (width, height))
                vo.add_frame(frame, mask, frame_depth)
                bar.update()
        result = vo.finish()
        ctx.log.info("visual odometry: %s; median tracked ratio %.2f", result.message,
                     float(np.median(result.tracking_ratio)))
        if result.static_camera:
            ctx.log.warning("the camera barely moved: odometry gives rotation only (pass --static-camera if it "
                            "stood still)")
        source = "patch visual odometry (m3c.vo)" + (" with DPVO's networks" if front_end is not None else "")
        return {"world_from_cam": result.world_from_cam, "points": result.points, "source": source}
