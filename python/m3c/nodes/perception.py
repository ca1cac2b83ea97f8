"""The perception node: every person in every frame, in one streaming pass of m3c.perception (thesis levels 1-3).

Another detector, segmenter, 2D pose estimator, body regressor or contact estimator plugs in as an estimator of
m3c.perception's registry (m3c.perception.registry.register), chosen by `perception.estimators`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import encode_packed_masks
from m3c.pipeline import ComponentUnavailable, InputError, Node, register_node


@register_node
class PerceptionNode(Node):
    """People in every frame, in one streaming pass (m3c.perception.run_perception_frames): detection (with the
    tracker's predicted boxes as proposals between detector runs), segmentation, the thesis's isolated square
    patches (5 px padding, shifted inside the frame, other people whitened), 2D keypoints, appearance-aware
    tracking; then per track the camera-local body fit (warm-started frame to frame) and contacts.

    One node rather than one per task because the tasks feed each other within a frame: the tracker's
    predictions are the detector's proposals, and each person's patch is isolated from everyone found in the
    frame. Outputs (m3c.perception.handover): tracks, each person's track whole (frames, tight and square boxes,
    scores, keypoints with the foot points, camera-local bodies, contacts), and the same people frame by frame:
    detections (frame, box, square, score) and masks, the per-detection tables of m3c.nodes.records, one row per
    tracked person per frame (people of unconfirmed tracks and frames whose body fit failed are left out).

    Config: estimators (task -> name or {name, options}; m3c.perception.available(task) lists them),
    padding (pixels around a tight box before it is squared, for the square boxes handed over; the thesis's 5),
    and any other m3c.perception.PerceptionConfig setting under `options` (tracker, detect_every, ground_motion,
    contact_depth_window, ...).

    The thesis's networks: 2D pose and body left unnamed become `vitpose` and `hmr2` when their official
    checkpoints lie in the models folder (--checkpoints / settings.models_dir / $M3C_MODELS, at
    NETWORK_CHECKPOINTS' paths); named without a `checkpoint` option, they read it from there. The resolved names
    are written into the node's config, so the cache key and results.json record which backend ran.
    """

    type_name = "perception"
    level = "patch"
    inputs = ("video", "camera")
    outputs = ("detections", "masks", "tracks")
    settings = ("body_model", "models_dir")
    # 2: the body fit retries a drifting warm start cold without its velocity prediction (cpp/fit)
    # 3: the tracker keeps recent poses and locations, gates on colour, matches tentative tracks last; track
    #    splits are merged; the detector searches smaller tiles every 15 frames
    # 4: contacts read the feet's motion against the ground from the images
    # 5: boxes and keypoints in M3C's pixel convention (m3c.perception.boxes): MediaPipe's shifted by -0.5 px
    #    and the body fit reads no velocity across a cold fit (cpp/fit)
    # 6: the tracks handed over whole (m3c.perception.handover), with the square boxes (padding) and foot keypoints
    # 7: planted feet from their motion relative to the body in a moving camera; the ground's contacts apart;
    #    a lost track reclaims a detection the first cascade stage gave to another (tracking.reclaim_margin)
    # 8: the body fit's translation prior 3000 -> 100 (its constant-velocity prediction made the depth wander)
    # 9: no static_camera setting: the contacts use one rule in any camera (3D foot speeds of monocular fits
    #    failed), on the fits with their depth steadied (m3c.perception.contacts.steady_depth)
    # 10: a warm body fit that ends turned more than 90 degrees from the 3D torso is solved again turned as it
    #    (cpp/fit max_turn_from_3d_deg: side views held on the wrong side)
    # 11: the detector's proposals from a multi-person pose network (m3c.perception.paf) before BlazePose's tiles
    # 12: a patch BlazePose finds nobody on, shifted into the frame at its edge, is retried centred on the person
    #     (white past the edge)
    # 13: a pose pass that re-runs BlazePose on a patch among more whitened people and finds nobody keeps the
    #     person's earlier BlazePose pose instead of dropping the person
    # 14: frames of a track that slid onto a person coming back are handed to that person's track
    #     (m3c.perception.track_merge.hand_back_slides)
    # 15: a track whose keypoint colours change for good as its own person comes back as a new track is split
    #     there (m3c.perception.track_merge.split_colour_changes)
    # 16: a slid frame nearer the returning pose than the track's own by less than SLIDE_RATIO is a blend of the two
    #     people, dropped instead of handed on
    # 17: a tracked person BlazePose finds nobody on may be kept on the detector's multi-person network skeleton
    #     (skeleton_agreement, opt-in); a piece inside another track's gap may join it by its keypoint colours
    #     (merge.max_piece_colour)
    # 18: a warm body fit with a knee, ankle, elbow or wrist over 0.25 m from the 3D is solved again from the pose
    #     of the 3D alone (cpp/fit max_limb_from_3d_m: a walker seen from behind kept a knee bent backwards)
    # 19: the fit's learned pose prior (cpp/fit vposer_weight, SMPLify-style; the body estimator's pose_prior option)
    version = "19"

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
        try:  # the learned pose prior the fit uses: its weights' digest
            prior = self._fit_pose_prior(self._perception_config())
        except (ValueError, FileNotFoundError):
            prior = None  # check() reports it
        if prior is not None:
            digests["pose_prior"] = file_digest(prior)
        if digests:
            config["checkpoint_digests"] = digests
        return config

    @staticmethod
    def _fit_pose_prior(config):
        """The weights of the learned pose prior the `fit` body estimator of a PerceptionConfig uses (None: none,
        or another body estimator); ValueError / FileNotFoundError when its setting names none that exists."""
        from m3c.perception.body import DEFAULT_POSE_PRIOR, pose_prior_file

        body = config.estimators["body"]
        return pose_prior_file(body.options.get("pose_prior", DEFAULT_POSE_PRIOR)) if body.name == "fit" else None

    @dataclass
    class Config:
        estimators: dict[str, Any] = field(default_factory=dict)
        padding: float = 5.0  # pixels around a tight box before it is squared (patches and square boxes)
        options: dict[str, Any] = field(default_factory=dict)

    def _perception_config(self, intrinsics=None, body_model: str | None = None):
        from m3c.perception import PerceptionConfig

        data = {**self.config.options, **self.config.estimators, "padding": self.config.padding}
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
        try:
            self._fit_pose_prior(config)
        except (ValueError, FileNotFoundError) as err:
            raise InputError(f"node {self.name!r}: the body fit's {err}") from None
        users = sorted(task for task, spec in config.estimators.items() if spec.name == NAME)
        if users and not mediapipe_available():
            raise ComponentUnavailable(self.name, f"MediaPipe (the {', '.join(users)} estimator)",
                                       "install it with pip install 'm3c[perception]' (mediapipe==0.10.14, "
                                       "its pose models ship inside the wheel)")

    def run(self, ctx, inputs):
        import cv2

        from m3c.perception import run_perception_frames
        from m3c.perception.handover import hand_over

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
        tracks, detections, masks = hand_over(result, config.padding)
        return {"detections": detections, "masks": encode_packed_masks(masks), "tracks": {"tracks": tracks}}

    def visualize(self, ctx, inputs, outputs, folder):
        """The frame with the most people: their tight boxes (green) and the square boxes handed over (red)."""
        import cv2

        detections = outputs["detections"]
        if len(detections["frame"]) == 0:
            return []
        target = int(np.argmax(np.bincount(detections["frame"])))
        for i, frame in stream_frames(ctx, inputs["video"]):
            if i == target:
                break
        for n in np.flatnonzero(detections["frame"] == target):
            for box, colour in ((detections["box"][n], (0, 200, 0)), (detections["square"][n], (0, 0, 255))):
                cv2.rectangle(frame, tuple(int(round(v)) for v in box[:2]), tuple(int(round(v)) for v in box[2:]),
                              colour, 2)
        path = folder / f"boxes_frame{target:05d}.jpg"
        cv2.imwrite(str(path), frame)
        return [path]
