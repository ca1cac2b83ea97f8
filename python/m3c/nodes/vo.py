"""The vo node: the camera's poses from M3C's patch visual odometry (m3c.vo) with the people hidden from it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import people_mask, rows_by_frame
from m3c.pipeline import ComponentUnavailable, InputError, Node, PipelineError, register_node
from m3c.vo.scale import MAX_WANDER, MIN_BASELINE, translation_baseline, turns_in_place


def odometry_fit(result) -> dict:
    """How well the kept run explains its own measurements (m3c.vo.VOResult.keyframe_fit_rms, pixels at the
    processing resolution; None without a map) and, when several ran, each run's fit when they were compared, and
    after how many frames."""
    def px(value):
        return float(value) if np.isfinite(value) else None

    stats = result.stats
    runs = int(stats.get("hypotheses", 1))
    return {"keyframe_rms_px": px(result.keyframe_fit_rms), "runs": runs,
            "kept": int(stats.get("hypothesis_kept", 0)),
            "runs_rms_px": [px(stats[f"hypothesis_{i}_fit_rms_px"]) for i in range(runs)] if runs > 1 else None,
            "compared_after_frames": int(stats["hypotheses_compared_at"]) if runs > 1 else None}


@register_node
class VisualOdometryNode(Node):
    """Camera poses world_from_cam (T, 4, 4); the world is the first camera's frame, translation up to scale.

    backend "patch" (default): M3C's patch visual odometry (m3c.vo), streaming the frames, with every person's
    mask (from the masks and detections inputs) hidden from it, and depth maps when the depth node gives them;
    options: m3c.vo.VOConfig settings. Its front-end (method): "lk" Lucas-Kanade, "dpvo" DPVO's networks
    (m3c.vo.dpvo, the official dpvo.pth from `checkpoint` or the models folder), "auto" dpvo when that file is
    there; backend names the odometry (only "patch" is built in). Output cameras: world_from_cam (T, 4, 4), static,
    source, points (M, 3) the odometry's map when it gives one, fit (odometry_fit: how well the kept run, of
    vo.options.hypotheses, explains its measurements); rotation_only when the camera turned in place
    (m3c.vo.scale.turns_in_place: translations zeroed). With static: true
    the camera is taken not to move (identity poses) and no odometry runs."""

    type_name = "vo"
    # 2: m3c.vo runs VOConfig.hypotheses odometries and keeps the best fit; 3: a camera the odometry saw no
    # baseline for (translation zero) is marked rotation_only, as one that turned in place
    version = "3"
    level = "patch"
    inputs = ("video", "masks", "detections", "depth", "camera")
    optional_inputs = ("masks", "detections", "depth")
    outputs = ("cameras",)
    settings = ("models_dir",)

    @dataclass
    class Config:
        backend: str = "patch"
        options: dict[str, Any] = field(default_factory=dict)  # m3c.vo.VOConfig settings
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
        if self.config.backend != "patch":
            raise InputError(f"node {self.name!r}: backend must be 'patch' (M3C's patch visual odometry; "
                             f"vo.method picks its front-end), got {self.config.backend!r}")
        self._vo_config()
        try:
            self._dpvo_checkpoint(ctx)
        except CheckpointNotFoundError as err:
            raise ComponentUnavailable(self.name, "DPVO's checkpoint", str(err)) from None

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
        out = self._patch_vo(ctx, inputs)
        poses = np.asarray(out.get("world_from_cam"), dtype=np.float64)
        if poses.shape != (T, 4, 4) or not np.isfinite(poses).all():
            raise PipelineError(f"node {self.name!r}: world_from_cam must be ({T}, 4, 4) and finite, got "
                                f"{poses.shape}")
        cameras = {"world_from_cam": poses, "static": False, "source": str(out.get("source", self.config.backend))}
        if out.get("static_camera"):  # the odometry never saw a baseline: translation zero, rotation fitted
            cameras["rotation_only"] = True
        if out.get("fit") is not None:
            cameras["fit"] = out["fit"]
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
        return {"world_from_cam": result.world_from_cam, "points": result.points, "source": source,
                "fit": odometry_fit(result), "static_camera": bool(result.static_camera)}
