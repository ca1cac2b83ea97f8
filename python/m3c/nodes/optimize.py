"""Global optimization (thesis 4.1.4): every lifted track refined in the world by m3c.motion.optimize."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from m3c.camera import WorldCameras
from m3c.motion import Cameras, OptimizerConfig, Track
from m3c.motion.windows import check_windows, optimize_in_windows
from m3c.pipeline import Node, PipelineError, register_node
from m3c.pipeline.finite import index_ranges

SHIPPED = "shipped"  # optimize.pose_prior / motion_prior naming M3C's own prior (m3c.models.weights)


def optimizer_config(overrides: dict) -> OptimizerConfig:
    """The default recipe (from the C++ core) with `overrides` (the YAML mapping of OptimizerConfig) applied."""
    try:
        return OptimizerConfig.from_yaml(yaml.safe_dump(overrides)) if overrides else OptimizerConfig.default()
    except (TypeError, ValueError) as err:
        raise PipelineError(f"optimize.optimizer: {err}") from None


def to_motion_track(track: dict, metric_world_from_cam: np.ndarray) -> Track:
    """The optimizer's Track. Its ground planes are given in each frame's camera coordinates (metric), so that
    they move with the camera scale it estimates: n_cam = R^T n, d_cam = d + n . C for the world plane
    n . x + d = 0 and the camera at C."""
    normal, offset = track.get("ground_normal"), track.get("ground_offset")
    if normal is not None:
        first = int(track["first_frame"])
        cams = metric_world_from_cam[first:first + len(normal)]
        normal = np.asarray(normal, dtype=np.float64)
        offset = np.asarray(offset, dtype=np.float64) + np.einsum("tj,tj->t", normal, cams[:, :3, 3])
        normal = np.einsum("tji,tj->ti", cams[:, :3, :3], normal)
    return Track(int(track["first_frame"]), np.asarray(track["keypoints"], dtype=np.float64),
                 np.asarray(track["transl"]), np.asarray(track["root_orient"]), np.asarray(track["body_pose"]),
                 np.asarray(track["betas"]), normal, offset, track.get("contacts"), track.get("ground_contacts"))


def walking_heading_config(settings: dict):
    """optimize.walking_heading as m3c.motion.heading.WalkingHeadingConfig, or a PipelineError naming the bad one."""
    from m3c.motion.heading import WalkingHeadingConfig

    try:
        config = WalkingHeadingConfig(**settings)
        config.validate()
    except (TypeError, ValueError) as err:
        raise PipelineError(f"optimize.walking_heading: {err} (settings: m3c.motion.heading.WalkingHeadingConfig "
                            "fields)") from None
    return config


def with_walking_heading(model, track: dict, times: np.ndarray, config) -> tuple[dict, np.ndarray]:
    """The track with its walking frames turned to face their direction of travel (m3c.motion.heading), and the
    turn per frame (radians); up is the track's mean ground normal (y where it has none)."""
    from m3c.motion.heading import turn_to_walking_direction

    normal = track.get("ground_normal")
    up = np.mean(np.asarray(normal, dtype=np.float64), axis=0) if normal is not None else np.array([0.0, 1.0, 0.0])
    first, n = int(track["first_frame"]), len(track["root_orient"])
    root, turn = turn_to_walking_direction(model, track["root_orient"], track["body_pose"], track["betas"],
                                           track["transl"], up, times[first:first + n], config)
    return {**track, "root_orient": root}, turn


def unusable_reason(model, track: Track, metric_world_from_cam: np.ndarray, config: OptimizerConfig) -> str | None:
    """Why the optimizer cannot use a track (None when it can): no keypoint it would score (confidence >=
    config.min_confidence), or a scored keypoint of the starting body at or behind its camera (closer than
    config.min_depth): the reprojection cost cannot be evaluated there, and a stage whose start cannot be evaluated
    fails for every track (a NaN objective)."""
    scored = np.asarray(track.keypoints)[..., 2] >= config.min_confidence
    if not scored.any():
        return f"none of its {track.num_frames} frames has a keypoint of confidence >= {config.min_confidence}"
    pose = np.concatenate([np.asarray(track.root_orient)[:, None], np.asarray(track.body_pose)], axis=1)
    points = model.keypoints(model.coco17_regressor(), pose, np.asarray(track.betas), np.asarray(track.transl))
    cams = metric_world_from_cam[track.first_frame:track.first_frame + track.num_frames]
    depth = np.einsum("ni,nki->nk", cams[:, :3, 2], points - cams[:, None, :3, 3])
    close = np.flatnonzero((scored & ~(depth > config.min_depth)).any(axis=1))
    if len(close):
        return (f"its starting body puts keypoints at or behind the camera (depth <= {config.min_depth} m, as close "
                f"as {float(np.min(depth[close])):.2f} m) in frames {index_ranges(close + track.first_frame)}: a "
                "camera-local body estimate that failed there")
    return None


@register_node
class OptimizeNode(Node):
    """Output result: tracks (the lift's tracks with optimised transl, root_orient, body_pose, betas), cameras
    (m3c.camera.WorldCameras fields: the lift's cameras at the optimised scale and offset, per frame when optimised
    in windows), camera_scale, camera_offset (3,) (the figures results report: frame-weighted means over windows),
    stages (per stage: name, status, message, iterations, objective_before, objective_after, terms {term: [before,
    after]}), stopped_early, optimized (False when disabled)."""

    version = "8"  # 2: cameras (WorldCameras) replace the metric world_from_cam; 3: contact_height on
    # ground_contacts; 4: the default recipe's joint_acceleration 10 -> 30; 5: walking_heading; 6: its gait needs
    # the track to travel (m3c.eval.plausibility.GAIT_MIN_TRAVEL_MPS); 7: end_motion_anchor in the default recipe;
    # 8: contact_height holds each contact joint at its rest height above the sole, not at the sole
    type_name = "optimize"
    level = "track"
    inputs = ("video", "camera", "world")
    outputs = ("result",)
    settings = ("body_model", "models_dir")
    nonfinite_outputs = ("result.stages",)  # a failed stage reports the objective it could not evaluate as NaN

    @dataclass
    class Config:
        enabled: bool = True
        optimizer: dict[str, Any] = field(default_factory=dict)  # OptimizerConfig fields to override
        # free: the stages that free the camera scale refine the scale estimator's value within its uncertainty
        # (scale_prior); fixed: it stays at the estimator's.
        scale: Literal["free", "fixed"] = "free"
        # Exported weights (python -m m3c.models.export --out DIR): humor.safetensors adds HuMoR's motion prior,
        # vposer.safetensors VPoser's pose prior (with latent pose variables). None: $M3C_MODELS/export/<file>
        # when it is there, else the stages run without the term (and report it unavailable). "shipped": M3C's own
        # prior (m3c.models.weights, non-commercial); "none": never.
        motion_prior: str | None = None
        pose_prior: str | None = None
        # Long videos are optimised in windows of this many frames overlapping by window_overlap, blended
        # (m3c.motion.windows): memory stays that of one window. 0 = one problem however long the video.
        window: int = 900
        window_overlap: int = 60
        # Walkers face where they walk: the start (and heading_anchor's reference) of each walking frame turned to
        # its direction of travel (m3c.motion.heading.WalkingHeadingConfig: enabled, min_speed, max_turn_deg,
        # half_window_s).
        walking_heading: dict[str, Any] = field(default_factory=dict)

    def _weights(self, ctx, setting: str, file_name: str) -> Path | None:
        value = getattr(self.config, setting)
        if value == "none":
            return None
        if value == SHIPPED:
            from m3c.models.weights import shipped_humor_runtime, shipped_vposer_runtime

            try:
                return shipped_vposer_runtime() if setting == "pose_prior" else shipped_humor_runtime()
            except FileNotFoundError as err:
                raise PipelineError(f"optimize.{setting}: {err}") from None
        if value is not None:
            path = Path(value).expanduser()
            if not path.is_file():
                raise PipelineError(f"optimize.{setting}: {path} does not exist; export it with "
                                    f"python -m m3c.models.export --out DIR (it writes DIR/{file_name})")
            return path
        folder = ctx.models_dir()
        path = folder / "export" / file_name if folder is not None else None
        return path if path is not None and path.is_file() else None

    def key_config(self, ctx):
        from m3c.pipeline.cache import file_digest

        # The resolved recipe: a changed default in the core re-runs the optimization; so do other weights.
        priors = {name: self._weights(ctx, name, f"{net}.safetensors")
                  for name, net in (("motion_prior", "humor"), ("pose_prior", "vposer"))}
        return {"enabled": self.config.enabled, "optimizer": asdict(optimizer_config(self.config.optimizer)),
                "scale": self.config.scale, "window": self.config.window, "window_overlap": self.config.window_overlap,
                "walking_heading": asdict(walking_heading_config(self.config.walking_heading)),
                **{name: file_digest(p) if p is not None else None for name, p in priors.items()}}

    def check(self, ctx) -> None:
        optimizer_config(self.config.optimizer)
        walking_heading_config(self.config.walking_heading)
        try:
            check_windows(self.config.window, self.config.window_overlap)
        except ValueError as err:
            raise PipelineError(f"optimize: {err}") from None
        self._weights(ctx, "motion_prior", "humor.safetensors")
        self._weights(ctx, "pose_prior", "vposer.safetensors")

    def run(self, ctx, inputs):
        world = inputs["world"]
        lifted = WorldCameras(**world["cameras"])
        video = inputs["video"]
        cameras = Cameras.from_world(lifted, np.asarray(inputs["camera"]["intrinsics"], dtype=np.float64),
                                     static=bool(world["static"]), scale_sigma=world.get("scale_sigma"),
                                     times=np.asarray(video["times"]) if video.get("variable_rate") else None)
        tracks = world["tracks"]
        if not self.config.enabled or not tracks:
            if tracks:
                ctx.log.warning("optimization disabled: results are the world lift")
            return {"result": {"tracks": tracks, "cameras": lifted.as_dict(), "camera_scale": cameras.initial_scale,
                               "camera_offset": np.zeros(3), "stages": [],
                               "stopped_early": False, "optimized": False}}
        config = optimizer_config(self.config.optimizer)
        if self.config.scale == "fixed":
            for stage in config.stages:
                stage.free = [v for v in stage.free if v != "scale"]
        metric = lifted.world_from_cam()
        heading = walking_heading_config(self.config.walking_heading)
        times = np.asarray(video["times"], dtype=np.float64)
        motion_tracks, usable = [], []
        for track in tracks:
            walker, turn = with_walking_heading(ctx.loaded("body_model"), track, times, heading)
            if turn.any():
                ctx.log.info("track %s: %d of %d frames walking, turned to face their direction of travel (median "
                             "%.1f degrees)", track["track_id"], np.count_nonzero(turn), len(turn),
                             np.degrees(np.median(np.abs(turn[turn != 0]))))
            motion = to_motion_track(walker, metric)
            reason = unusable_reason(ctx.loaded("body_model"), motion, metric, config)
            if reason is not None:
                ctx.log.warning("track %s dropped: the optimizer cannot use it: %s", track["track_id"], reason)
                continue
            motion_tracks.append(motion)
            usable.append(track)
        if not usable:
            raise PipelineError(f"none of the {len(tracks)} track(s) can be optimised (see the warnings above); "
                                "disable the optimization (--set optimize.enabled=false) to keep the world lift")
        tracks = usable
        motion_prior = self._weights(ctx, "motion_prior", "humor.safetensors")
        pose_prior = self._weights(ctx, "pose_prior", "vposer.safetensors")
        for name, path in (("HuMoR motion prior", motion_prior), ("VPoser pose prior", pose_prior)):
            ctx.log.info("%s: %s", name, path if path is not None else "no weights (term left out)")
        result = optimize_in_windows(ctx.loaded("body_model"), motion_tracks, cameras, config, self.config.window,
                                     self.config.window_overlap, ctx.log, motion_prior=motion_prior,
                                     pose_prior=pose_prior, fps=float(inputs["video"]["fps"]))
        optimised = result.world_cameras(cameras)
        lift = _ground_lift(motion_tracks, optimised.world_from_cam())
        final = replace(optimised, offset=optimised.offset + lift)  # the ground back at y = 0
        out_tracks = []
        for track, optimized in zip(tracks, result.tracks):
            out = dict(track)
            out.update(transl=optimized.transl + lift, root_orient=optimized.root_orient,
                       body_pose=optimized.body_pose, betas=optimized.betas)
            out_tracks.append(out)
        stages = []
        for stage in result.stages:
            ctx.log.info("stage %-12s %-10s %3d iterations, objective %.4g -> %.4g (%.2f s%s)", stage.name,
                         stage.status, stage.iterations, stage.objective_before, stage.objective_after,
                         stage.seconds, f", {stage.parts} problems" if stage.parts > 1 else "")
            # Stage times stay in the log: results depend only on the inputs.
            stages.append({"name": stage.name, "status": stage.status, "message": stage.message,
                           "iterations": int(stage.iterations), "parts": int(stage.parts),
                           "objective_before": float(stage.objective_before),
                           "objective_after": float(stage.objective_after), "scale": float(stage.camera_scale),
                           "world_before": float(stage.world_before), "world_after": float(stage.world_after),
                           "terms": {k: [float(v[0]), float(v[1])] for k, v in stage.terms.items()}})
        if result.stopped_early:
            ctx.log.warning("optimization stopped early (a stage failed); results are from the last good step")
        return {"result": {"tracks": out_tracks, "cameras": final.as_dict(),
                           "camera_scale": float(result.camera_scale), "camera_offset": result.camera_offset + lift,
                           "stages": stages, "stopped_early": bool(result.stopped_early), "optimized": True,
                           "windows": getattr(result, "windows", None) or []}}


def _ground_lift(motion_tracks: list[Track], final_world_from_cam: np.ndarray) -> np.ndarray:
    """The translation that puts the people's ground back at the world's y = 0 after the optimizer changed the
    camera scale: the camera-frame planes expressed with the final cameras give world planes n.x + d = 0, and
    moving everything by median(d) n (n their mean normal) brings them to 0. Zero when no track has a ground."""
    normals, offsets = [], []
    for track in motion_tracks:
        if track.ground_normal is None:
            continue
        cams = final_world_from_cam[track.first_frame:track.first_frame + track.num_frames]
        n = np.einsum("tij,tj->ti", cams[:, :3, :3], np.asarray(track.ground_normal))
        normals.append(n)
        offsets.append(np.asarray(track.ground_offset) - np.einsum("tj,tj->t", n, cams[:, :3, 3]))
    if not normals:
        return np.zeros(3)
    normal = np.concatenate(normals).mean(axis=0)
    normal /= np.linalg.norm(normal)
    return float(np.median(np.concatenate(offsets))) * normal
