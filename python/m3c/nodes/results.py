"""The results node: results.npz and results.json (m3c.io.results describes them), assembled by build_results."""

from __future__ import annotations

import json

import numpy as np

import m3c
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.camera import WorldCameras, project, to_camera
from m3c.eval.plausibility import results_plausibility
from m3c.motion.time_scale import estimate_time_scale
from m3c.ground.tracks import track_frames, track_poses
from m3c.io.npz import write_npz
from m3c.io.results import ARRAYS, SCHEMA, check_arrays, json_ready
from m3c.pipeline import FileRef, Node, register_node

MIN_CONFIDENCE = 0.4  # keypoints below this confidence are not scored (the optimizer ignores them too)


def build_results(model, video: dict, camera: dict, cameras: dict, scale: dict, ground: dict, world: dict,
                  result: dict, backends: dict, lean: dict | None = None,
                  hands: dict | None = None) -> tuple[dict, dict]:
    """(arrays of results.npz, summary of results.json); see m3c.io.results.ARRAYS for the arrays. lean: the lean
    node's tracks output (its per-track records go into each track's "lean"). hands: the hands node's output
    (its finger poses and landmarks, posed on the optimizer's wrists)."""
    leaned = {r["track_id"]: r for r in (lean or {}).get("lean", [])}
    handed = {t["track_id"]: t for t in (hands or {}).get("tracks", [])}
    T = int(video["num_frames"])
    tracks = result["tracks"]
    P, B = len(tracks), model.num_betas
    J = model.num_joints
    nan = np.float32(np.nan)
    world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
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
        "lift_world_from_cam": WorldCameras(**world["cameras"]).world_from_cam().astype(np.float32),
    }
    for name, shape in (("world_root_orient", (3,)), ("world_transl", (3,)), ("body_pose", (J - 1, 3)),
                        ("world_joints", (J, 3)), ("cam_root_orient", (3,)), ("cam_transl", (3,)),
                        ("lift_world_root_orient", (3,)), ("lift_world_transl", (3,)),
                        ("lift_body_pose", (J - 1, 3)), ("keypoints_2d", (17, 3)),
                        ("contacts", (4,)), ("ground_normal", (3,)), ("ground_offset", ()),
                        ("reprojection_error", ()), ("left_hand_pose", (15, 3)), ("right_hand_pose", (15, 3)),
                        ("hand_keypoints_2d", (2, 21, 3)), ("world_hand_keypoints", (2, 21, 3))):
        arrays[name] = np.full((P, T) + shape, nan)
    regressor = model.coco17_regressor()
    summary_tracks = []
    lifted_by_id = {t["track_id"]: t for t in world["tracks"]}  # the optimizer may have dropped tracks
    for p, track in enumerate(tracks):
        lifted = lifted_by_id[track["track_id"]]
        frames = track_frames(track)
        hand = handed.get(track["track_id"])
        betas = np.asarray(track["betas"], dtype=np.float64)
        pose = track_poses(track)
        transl = np.asarray(track["transl"], dtype=np.float64)
        arrays["valid"][p, frames] = True
        arrays["visible"][p, frames] = track["visible"]
        arrays["betas"][p] = betas
        arrays["world_root_orient"][p, frames] = track["root_orient"]
        arrays["world_transl"][p, frames] = transl
        arrays["body_pose"][p, frames] = track["body_pose"]
        joints = model.joints(pose, betas, transl)
        arrays["world_joints"][p, frames] = joints
        if hand is not None:
            arrays["left_hand_pose"][p, frames] = hand["hand_pose"][:, 0]
            arrays["right_hand_pose"][p, frames] = hand["hand_pose"][:, 1]
            arrays["hand_keypoints_2d"][p, frames] = hand["keypoints"]
            # On the optimizer's wrists, as the exports pose them: the hand fit's own wrist refinement, frame by
            # frame, raised the body's jitter 140 -> 203 mm/s^2 on the default video set (seed 0) when it replaced
            # them, so it only helps the finger fit.
            arrays["world_hand_keypoints"][p, frames] = world_hand_keypoints(model, pose, betas, transl,
                                                                             hand["hand_pose"])
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
        predicted = project(to_camera(model.keypoints(regressor, pose, betas, transl), world_from_cam[frames]),
                            intrinsics[frames][:, None])
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
            # m3c.perception.lean: the track's median lean towards the camera against the scene's up, and its re-fit
            "lean": json_ready(leaned.get(int(track["track_id"]))),
        })
    for name, (_, dtype, _) in ARRAYS.items():
        if dtype == "float32":
            arrays[name] = np.asarray(arrays[name], dtype=np.float32)
    check_arrays(arrays)
    for entry, figures in zip(summary_tracks, results_plausibility(arrays)):
        entry["plausibility"] = figures
    slow = float(video.get("slow_motion", 1.0))
    time_scale = estimate_time_scale([entry["plausibility"] for entry in summary_tracks], applied=slow)
    summary = {
        "schema": SCHEMA,
        "m3c_version": m3c.__version__,
        "video": {"name": video["name"], "fps": float(video["fps"]),
                  "variable_frame_rate": bool(video.get("variable_rate", False)), "width": int(video["width"]),
                  "height": int(video["height"]), "frames": T,
                  "frame_range": [int(video["start"]), int(video["stop"]), int(video["step"])],
                  "slow_motion": slow,
                  # frames 0 .. total_frames - 1 exist; a cut file lists more in its container
                  "total_frames": int(video.get("total_frames", video["stop"])),
                  "frames_in_container": int(video.get("frames_in_container", 0)),
                  "truncated": bool(video.get("truncated", False)),
                  # m3c.motion.time_scale: the slow motion the people's gait says (reported, not applied)
                  "time_scale": json_ready(time_scale)},
        "world": {"frame": "gravity-aligned, y up, metres; origin on the ground below the first camera, +z its "
                           "viewing direction", "ground": "y = 0" if ground["up_source"] == "ground" else
                  "not found (up from the first camera)", "ground_source": ground.get("ground_source"),
                  "ground_tilt_prior": ground.get("tilt_prior"),
                  "contact_points": int(ground["contact_points"])},
        "body_model": {"name": model.data.name, "gender": model.data.gender, "num_betas": int(B),
                       "num_joints": int(J)},
        "camera": {"intrinsics": [float(v) for v in camera["intrinsics"]], "intrinsics_source": camera["source"],
                   "static": bool(cameras["static"]), "odometry": cameras["source"],
                   # the odometry found no translation it could trust (turned in place, or never a baseline)
                   "rotation_only": bool(cameras.get("rotation_only", False)),
                   # m3c.nodes.vo.odometry_fit: the kept odometry run's keyframe reprojection rms (px) and the others'
                   "odometry_fit": json_ready(cameras.get("fit")),
                   "scale": float(result["camera_scale"]), "scale_source": scale["source"],
                   # m3c.vo.scale's estimate: value, sigma (standard deviation of log(value)), every observation
                   "scale_estimate": json_ready(scale),
                   # m3c.vo.focal's search when the focal node ran one: focal, log_sigma, informative, costs
                   "focal_estimate": json_ready(camera.get("focal_estimate")),
                   # m3c.vo.vanishing's estimate from the scene's lines: focal, informative, per frame up direction
                   "scene": json_ready(camera.get("scene")),
                   # m3c.vo.ground_focal's estimate from a still camera's people: focal, measured, log_sigma, people
                   "feet_focal": json_ready(camera.get("feet_focal"))},
        "lift": {"method": world["method"]},
        # m3c.nodes.hands: whether it ran, the person-frames it searched, the hands it fitted, its time
        "hands": hands_summary(hands, T),
        "optimization": {"optimized": bool(result["optimized"]), "stopped_early": bool(result["stopped_early"]),
                         "stages": result["stages"], "windows": result.get("windows", [])},
        # which learned priors shaped the bodies, and the licence their weights carry
        "priors": priors_summary(backends, result["stages"]),
        "backends": backends,
        "tracks": summary_tracks,
        "arrays": {name: {"shape": shape, "dtype": dtype, "description": text}
                   for name, (shape, dtype, text) in ARRAYS.items()},
    }
    return arrays, summary


def world_hand_keypoints(model, pose: np.ndarray, betas: np.ndarray, transl: np.ndarray,
                         hand_pose: np.ndarray) -> np.ndarray:
    """n x 2 x 21 x 3 world points of the fitted hands (NaN where hand_pose is NaN) of SMPL poses n x 24 x 3."""
    from m3c.body.hands import hand_model_for, pose_hands, wrist_frames

    out = np.full(hand_pose.shape[:2] + (21, 3), np.nan)
    hand_model = hand_model_for(model.data.name)
    if hand_model is None:
        return out
    rotation, position = wrist_frames(model, pose, betas, transl)
    points = pose_hands(hand_model, betas, rotation, position, np.nan_to_num(hand_pose)).keypoints()
    found = np.isfinite(hand_pose).all(axis=(2, 3))
    out[found] = points[found]
    return out


def hands_summary(hands: dict | None, num_frames: int) -> dict:
    if hands is None:
        return {"enabled": False, "reason": "no hands node in the pipeline"}
    # No timings: a rerun (or m3c batch) must publish the same bytes; the node's time is in the run's log.
    return {"enabled": bool(hands["enabled"]), "reason": hands.get("reason"), "person_frames": int(hands["frames"]),
            "hands_fitted": int(hands["hand_frames"])}


SHIPPED_PRIOR_LICENCE = ("non-commercial (CC BY-NC 4.0): M3C's own priors are trained on the Bandai Namco Research "
                         "Motiondatasets (m3c/models/weights/MODEL_CARD.md)")


def priors_summary(backends: dict, stages: list) -> dict:
    """The per-frame fit's pose prior (the perception node's body estimator), the optimizer's pose_prior and
    motion_prior stages (ran, skipped and why, reverted), and the licence when one of M3C's shipped priors ran."""
    from m3c.perception.body import DEFAULT_POSE_PRIOR, BodyFitConfig

    estimators = (backends.get("perception") or {}).get("estimators") or {}
    body = estimators.get("body", "fit")
    name, options = (body, {}) if isinstance(body, str) else (body.get("name"), body.get("options") or {})
    fit = None
    if name == "fit":
        setting = options.get("pose_prior", DEFAULT_POSE_PRIOR)
        fit = {"pose_prior": setting, "vposer_weight": float(options.get("vposer_weight",
                                                                            BodyFitConfig().vposer_weight))}
    stage = {s["name"]: {"status": s["status"], "message": s.get("message", "")} for s in stages
             if s.get("name") in ("pose_prior", "motion_prior")}
    shipped = (fit is not None and fit["pose_prior"] == "shipped" and fit["vposer_weight"] > 0) or any(
        "shipped" in str((backends.get("optimize") or {}).get(k, "")) for k in ("pose_prior", "motion_prior"))
    return {"body_fit": fit, "stages": stage, "licence": SHIPPED_PRIOR_LICENCE if shipped else None}


@register_node
class ResultsNode(Node):
    # 2: results.json camera.scale_estimate, the optimizer stages' world check and scale; 3: camera.focal_estimate;
    # 4: camera.scene; 5: world.ground_tilt_prior; 6: the tracks' gait (plausibility step_rate_spm, step_length_*),
    # video.slow_motion; 7: a gait needs the track to travel; 8: camera.feet_focal; 9: the tracks' lean;
    # 10: video.time_scale, camera.scale_estimate's spread, confidence and disagreement; video.total_frames,
    # frames_in_container, truncated; 11: the tracks' legs (plausibility lead_changes, longest_lead_s, knee_flex_deg,
    # knee_bent_fraction, surge_ratio); 12: a step rate whose step is 0.4-0.6 leg lengths timed as a walk, not
    # confidently (m3c.motion.time_scale); 13: camera.rotation_only; 14: hands (left/right_hand_pose,
    # hand_keypoints_2d, world_hand_keypoints on the optimizer's wrists, results.json hands); 15: priors
    version = "15"
    type_name = "results"
    level = "output"
    inputs = ("video", "camera", "cameras", "scale", "ground", "world", "result", "lean", "hands")
    optional_inputs = ("lean", "hands")
    outputs = ("npz", "json")
    settings = ("body_model",)
    publish = {"npz": "results.npz", "json": "results.json"}

    def run(self, ctx, inputs):
        backends = {}
        for name, node in ctx.upstream_nodes().items():
            entry = {"type": node["type"]}
            for key in ("backend", "method", "static", "enabled", "estimators", "pose_prior", "motion_prior"):
                if key in node["config"]:
                    entry[key] = node["config"][key]
            backends[name] = entry
        arrays, summary = build_results(ctx.loaded("body_model"), inputs["video"], inputs["camera"], inputs["cameras"],
                                        inputs["scale"], inputs["ground"], inputs["world"], inputs["result"],
                                        backends, inputs.get("lean"), inputs.get("hands"))
        write_npz(ctx.work_path("results.npz"), arrays, compress=True)
        ctx.work_path("results.json").write_text(json.dumps(json_ready(summary), indent=1, allow_nan=False) + "\n")
        return {"npz": FileRef("results.npz"), "json": FileRef("results.json")}
