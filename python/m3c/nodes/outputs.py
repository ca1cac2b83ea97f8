"""Result nodes: results.npz + results.json, the overlay video, the world-view video, the camera-trajectory plot.
Each writes its files into its cache entry; the runner links them into the output folder (Node.publish)."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

import m3c
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.eval.plausibility import results_plausibility
from m3c.io.npz import write_npz
from m3c.io.results import ARRAYS, SCHEMA, check_arrays, json_ready
from m3c.io.video import VideoWriter
from m3c.nodes.frames import stream_frames
from m3c.ground.world_frame import metric_cameras
from m3c.pipeline import ComponentUnavailable, FileRef, Node, register_node

MIN_CONFIDENCE = 0.4  # keypoints below this confidence are not scored (the optimizer ignores them too)


def _poses(track: dict) -> np.ndarray:
    return np.concatenate([np.asarray(track["root_orient"])[:, None], np.asarray(track["body_pose"])], axis=1)


def _frames(track: dict) -> np.ndarray:
    return int(track["first_frame"]) + np.arange(int(track["num_frames"]))


def project(points: np.ndarray, world_from_cam: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """points (n, K, 3) world, one camera per row (n, 4, 4), intrinsics (n, 4) -> (n, K, 2) pixels."""
    R, c = world_from_cam[:, :3, :3], world_from_cam[:, :3, 3]
    cam = np.einsum("nji,nkj->nki", R, points - c[:, None])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([intrinsics[:, None, 0] * cam[..., 0] / cam[..., 2] + intrinsics[:, None, 2],
                         intrinsics[:, None, 1] * cam[..., 1] / cam[..., 2] + intrinsics[:, None, 3]], axis=-1)


def build_results(model, video: dict, camera: dict, cameras: dict, scale: dict, ground: dict, world: dict,
                  result: dict, backends: dict) -> tuple[dict, dict]:
    """(arrays of results.npz, summary of results.json); see m3c.io.results.ARRAYS for the arrays."""
    T = int(video["num_frames"])
    tracks = result["tracks"]
    P, B = len(tracks), model.num_betas
    J = model.num_joints
    nan = np.float32(np.nan)
    world_from_cam = np.asarray(result["world_from_cam"], dtype=np.float64)
    intrinsics = np.tile(np.asarray(camera["intrinsics"], dtype=np.float64), (T, 1))
    arrays = {
        "frame_ids": np.asarray(video["frame_ids"], dtype=np.int64),
        "times": np.asarray(video["times"], dtype=np.float64),
        "fps": np.float64(video["fps"]),
        "image_size": np.array([video["width"], video["height"]], dtype=np.int32),
        "intrinsics": intrinsics.astype(np.float32),
        "world_from_cam": world_from_cam.astype(np.float32),
        "camera_scale": np.float32(result["camera_scale"]),
        "camera_offset": np.asarray(result["camera_offset"], dtype=np.float32),
        "track_ids": np.array([t["track_id"] for t in tracks], dtype=np.int64),
        "gender": np.array([model.data.gender] * P, dtype=str) if P else np.zeros(0, dtype="<U7"),
        "valid": np.zeros((P, T), bool),
        "visible": np.zeros((P, T), bool),
        "betas": np.full((P, B), nan),
        "lift_betas": np.full((P, B), nan),
        "lift_world_from_cam": metric_cameras(world["world_from_cam"], world["initial_scale"]).astype(np.float32),
    }
    for name, shape in (("world_root_orient", (3,)), ("world_transl", (3,)), ("body_pose", (J - 1, 3)),
                        ("world_joints", (J, 3)), ("cam_root_orient", (3,)), ("cam_transl", (3,)),
                        ("lift_world_root_orient", (3,)), ("lift_world_transl", (3,)),
                        ("lift_body_pose", (J - 1, 3)), ("keypoints_2d", (17, 3)),
                        ("contacts", (4,)), ("ground_normal", (3,)), ("ground_offset", ()),
                        ("reprojection_error", ())):
        arrays[name] = np.full((P, T) + shape, nan)
    regressor = model.coco17_regressor()
    summary_tracks = []
    lifted_by_id = {t["track_id"]: t for t in world["tracks"]}  # the optimizer may have dropped tracks
    for p, track in enumerate(tracks):
        lifted = lifted_by_id[track["track_id"]]
        frames = _frames(track)
        betas = np.asarray(track["betas"], dtype=np.float64)
        pose = _poses(track)
        transl = np.asarray(track["transl"], dtype=np.float64)
        arrays["valid"][p, frames] = True
        arrays["visible"][p, frames] = track["visible"]
        arrays["betas"][p] = betas
        arrays["world_root_orient"][p, frames] = track["root_orient"]
        arrays["world_transl"][p, frames] = transl
        arrays["body_pose"][p, frames] = track["body_pose"]
        joints = model.joints(pose, betas, transl)
        arrays["world_joints"][p, frames] = joints
        cam_from_world = np.linalg.inv(world_from_cam[frames])
        cam_root, cam_transl = transform_smpl(cam_from_world, track["root_orient"], transl,
                                              rest_root_joint(model, betas))
        arrays["cam_root_orient"][p, frames] = cam_root
        arrays["cam_transl"][p, frames] = cam_transl
        arrays["lift_world_root_orient"][p, frames] = lifted["root_orient"]
        arrays["lift_world_transl"][p, frames] = lifted["transl"]
        arrays["lift_body_pose"][p, frames] = lifted["body_pose"]
        arrays["lift_betas"][p] = lifted["betas"]
        keypoints = np.asarray(track["keypoints"], dtype=np.float64)
        arrays["keypoints_2d"][p, frames] = keypoints
        if track.get("contacts") is not None:
            arrays["contacts"][p, frames] = track["contacts"]
        if track.get("ground_normal") is not None:
            arrays["ground_normal"][p, frames] = track["ground_normal"]
            arrays["ground_offset"][p, frames] = track["ground_offset"]
        predicted = project(model.keypoints(regressor, pose, betas, transl), world_from_cam[frames],
                            intrinsics[frames])
        distance = np.linalg.norm(predicted - keypoints[..., :2], axis=-1)
        scored = keypoints[..., 2] >= MIN_CONFIDENCE
        with np.errstate(invalid="ignore"):
            per_frame = np.where(scored.any(axis=1), (distance * scored).sum(axis=1) / scored.sum(axis=1), np.nan)
        arrays["reprojection_error"][p, frames] = per_frame
        roots = joints[:, 0]
        summary_tracks.append({
            "id": int(track["track_id"]), "first_frame": int(frames[0]), "last_frame": int(frames[-1]),
            "frames": int(len(frames)), "visible_frames": int(np.sum(track["visible"])),
            "mean_reprojection_error_px": float(np.nanmean(per_frame)) if np.isfinite(per_frame).any() else None,
            "path_length_m": float(np.linalg.norm(np.diff(roots, axis=0), axis=1).sum()),
            "height_m": float(np.ptp(model.forward(np.zeros((1, J, 3)), betas).vertices[0, :, 1])),
            "ground": "per-frame plane" if track.get("ground_normal") is not None else "none",
        })
    for name, (_, dtype, _) in ARRAYS.items():
        if dtype == "float32":
            arrays[name] = np.asarray(arrays[name], dtype=np.float32)
    check_arrays(arrays)
    for entry, figures in zip(summary_tracks, results_plausibility(arrays)):
        entry["plausibility"] = figures
    summary = {
        "schema": SCHEMA,
        "m3c_version": m3c.__version__,
        "video": {"name": video["name"], "fps": float(video["fps"]),
                  "variable_frame_rate": bool(video.get("variable_rate", False)), "width": int(video["width"]),
                  "height": int(video["height"]), "frames": T,
                  "frame_range": [int(video["start"]), int(video["stop"]), int(video["step"])]},
        "world": {"frame": "gravity-aligned, y up, metres; origin on the ground below the first camera, +z its "
                           "viewing direction", "ground": "y = 0" if ground["up_source"] == "ground" else
                  "not found (up from the first camera)", "contact_points": int(ground["contact_points"])},
        "body_model": {"name": model.data.name, "gender": model.data.gender, "num_betas": int(B),
                       "num_joints": int(J)},
        "camera": {"intrinsics": [float(v) for v in camera["intrinsics"]], "intrinsics_source": camera["source"],
                   "static": bool(cameras["static"]), "odometry": cameras["source"],
                   "scale": float(result["camera_scale"]), "scale_source": scale["source"],
                   # m3c.vo.scale's estimate: value, sigma (standard deviation of log(value)), every observation
                   "scale_estimate": json_ready(scale),
                   # m3c.vo.focal's search when the focal node ran one: focal, log_sigma, informative, costs
                   "focal_estimate": json_ready(camera.get("focal_estimate"))},
        "lift": {"method": world["method"]},
        "optimization": {"optimized": bool(result["optimized"]), "stopped_early": bool(result["stopped_early"]),
                         "stages": result["stages"], "windows": result.get("windows", [])},
        "backends": backends,
        "tracks": summary_tracks,
        "arrays": {name: {"shape": shape, "dtype": dtype, "description": text}
                   for name, (shape, dtype, text) in ARRAYS.items()},
    }
    return arrays, summary


@register_node
class ResultsNode(Node):
    # 2: results.json camera.scale_estimate, the optimizer stages' world check and scale; 3: camera.focal_estimate
    version = "3"
    type_name = "results"
    level = "output"
    inputs = ("video", "camera", "cameras", "scale", "ground", "world", "result")
    outputs = ("npz", "json")
    settings = ("body_model",)
    publish = {"npz": "results.npz", "json": "results.json"}

    def run(self, ctx, inputs):
        backends = {}
        for name, node in ctx.upstream_nodes().items():
            entry = {"type": node["type"]}
            for key in ("backend", "method", "static", "enabled", "estimators"):
                if key in node["config"]:
                    entry[key] = node["config"][key]
            backends[name] = entry
        arrays, summary = build_results(ctx.loaded("body_model"), inputs["video"], inputs["camera"], inputs["cameras"],
                                        inputs["scale"], inputs["ground"], inputs["world"], inputs["result"],
                                        backends)
        write_npz(ctx.work_path("results.npz"), arrays, compress=True)
        ctx.work_path("results.json").write_text(json.dumps(json_ready(summary), indent=1, allow_nan=False) + "\n")
        return {"npz": FileRef("results.npz"), "json": FileRef("results.json")}


class _BodyFrames:
    """World-frame vertices of every track at a frame, computed a chunk of frames at a time."""

    def __init__(self, model, tracks: list[dict], chunk: int = 16):
        self.model, self.tracks, self.chunk = model, tracks, chunk
        self._cache: dict[int, tuple[int, np.ndarray]] = {}

    def at(self, frame: int) -> list[tuple[np.ndarray, int]]:
        bodies = []
        for k, track in enumerate(self.tracks):
            i = frame - int(track["first_frame"])
            if not 0 <= i < int(track["num_frames"]):
                continue
            start, verts = self._cache.get(k, (-1, None))
            if verts is None or not start <= i < start + len(verts):
                start = i
                stop = min(i + self.chunk, int(track["num_frames"]))
                pose = _poses(track)[start:stop]
                verts = self.model.forward(pose, np.asarray(track["betas"]),
                                           np.asarray(track["transl"])[start:stop]).vertices
                self._cache[k] = (start, verts)
            bodies.append((verts[i - start], int(track["track_id"])))
        return bodies


@register_node
class OverlayNode(Node):
    """overlay.mp4: the final bodies rendered over the input frames (depth-tested, shaded, one colour per track)."""

    type_name = "overlay"
    level = "output"
    inputs = ("video", "camera", "result")
    outputs = ("video_file",)
    settings = ("body_model",)
    publish = {"video_file": "overlay.mp4"}

    @dataclass
    class Config:
        alpha: float = 0.8  # mesh opacity

    def run(self, ctx, inputs):
        from m3c.viz.scene import overlay_frame

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        bodies = _BodyFrames(model, result["tracks"])
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])
        world_from_cam = np.asarray(result["world_from_cam"])
        with VideoWriter(ctx.work_path("overlay.mp4"), video["fps"], (video["width"], video["height"])) as writer, \
                ctx.progress("rendering overlay", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                writer.write(overlay_frame(frame, bodies.at(i), model.faces, world_from_cam[i], intrinsics,
                                           self.config.alpha))
                bar.update()
        return {"video_file": FileRef("overlay.mp4")}


@register_node
class WorldViewNode(Node):
    """world.mp4: ground, people and the video camera (frustum and path so far) seen from a fixed virtual camera."""

    type_name = "world_view"
    level = "output"
    inputs = ("video", "camera", "ground", "result")
    outputs = ("video_file",)
    settings = ("body_model",)
    publish = {"video_file": "world.mp4"}

    @dataclass
    class Config:
        width: int = 960
        height: int = 540
        yaw: float = 35.0  # degrees about the up axis, from behind the first camera
        elevation: float = 30.0  # degrees above the ground

    def run(self, ctx, inputs):
        from m3c.viz.scene import WorldView

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        world_from_cam = np.asarray(result["world_from_cam"])
        roots = [np.asarray(t["transl"]) for t in result["tracks"]]
        people = np.concatenate(roots) if roots else np.zeros((0, 3))
        if inputs["ground"]["up_source"] == "ground":
            ground_height = 0.0
        else:  # no ground found: draw one under the lowest foot
            lows = [model.joints(_poses(t), np.asarray(t["betas"]), np.asarray(t["transl"]))[:, [7, 8, 10, 11], 1]
                    .min() for t in result["tracks"]]
            ground_height = float(min(lows)) - 0.05 if lows else 0.0
        view = WorldView(people, world_from_cam[:, :3, 3], ground_height, self.config.width, self.config.height,
                         self.config.yaw, self.config.elevation)
        bodies = _BodyFrames(model, result["tracks"])
        depth = 0.15 * view.tile * 4
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])
        with VideoWriter(ctx.work_path("world.mp4"), video["fps"], (self.config.width, self.config.height)) as writer, \
                ctx.progress("rendering world view", video["num_frames"]) as bar:
            for i in range(int(video["num_frames"])):
                writer.write(view.frame(bodies.at(i), model.faces, world_from_cam[:i + 1, :3, 3], world_from_cam[i],
                                        intrinsics, (video["width"], video["height"]), depth))
                bar.update()
        return {"video_file": FileRef("world.mp4")}


@register_node
class CameraPlotNode(Node):
    """camera_trajectory.png: top view of the camera path and the people's paths; camera height over time."""

    type_name = "camera_plot"
    level = "output"
    inputs = ("video", "result")
    outputs = ("plot",)
    settings = ("body_model",)
    publish = {"plot": "camera_trajectory.png"}

    def check(self, ctx) -> None:
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise ComponentUnavailable(self.name, "matplotlib", "install the viz extra (pip install 'm3c[viz]'), "
                                       "or remove the camera_plot node from the pipeline config")

    def run(self, ctx, inputs):
        from m3c.viz.plots import camera_trajectory_plot

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        people = [(int(t["track_id"]), model.joints(_poses(t), np.asarray(t["betas"]), np.asarray(t["transl"]))[:, 0])
                  for t in result["tracks"]]
        scale = f"{result['camera_scale']:.3f} m per odometry unit"
        camera_trajectory_plot(ctx.work_path("camera_trajectory.png"), np.asarray(result["world_from_cam"]),
                               float(video["fps"]), people, f"{video['name']}: camera trajectory ({scale})")
        return {"plot": FileRef("camera_trajectory.png")}
