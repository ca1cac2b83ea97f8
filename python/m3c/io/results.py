"""The result files of a run: OUT/results.npz (arrays) and OUT/results.json (summary and schema).

Per-track arrays are stacked over P tracks and T processed frames, NaN (or False, or -1) outside a track's
frames. World frame: gravity-aligned, y up, metres, ground plane y = 0 when one was found. Camera frame: OpenCV
(x right, y down, z forward). Rotations are axis-angle. SMPL parameters follow the body model named in the JSON.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from m3c.io.manifest import MANIFEST, check_complete, folder_state
from m3c.motion.time_scale import CONFIDENT_SIGMAS, MIN_FACTOR, UNCLASSIFIED_GAIT, gait_time_scale

SCHEMA = "m3c.results/1"

# name -> (shape, dtype, description); P tracks, T frames, B shape parameters.
ARRAYS: dict[str, tuple[str, str, str]] = {
    "frame_ids": ("T", "int64", "video frame index of each processed frame"),
    "times": ("T", "float64", "time of each processed frame in seconds (the video's timestamps)"),
    "fps": ("", "float64", "frame rate of the processed frames (video rate / frame step; a variable-rate video's "
                           "mean rate)"),
    "image_size": ("2", "int32", "width, height in pixels"),
    "intrinsics": ("T x 4", "float32", "fx, fy, cx, cy in pixels (pixel centres at integer coordinates)"),
    "world_from_cam": ("T x 4 x 4", "float32", "camera pose in the world (metres)"),
    "camera_scale": ("", "float32", "metres per visual-odometry translation unit"),
    "camera_offset": ("3", "float32", "world offset added to the scaled odometry camera centres"),
    "track_ids": ("P", "int64", "tracker id of each track"),
    "gender": ("P", "str", "body model gender used for each track"),
    "valid": ("P x T", "bool", "frame lies within the track (first..last detection); values defined"),
    "visible": ("P x T", "bool", "the person was detected in the frame (else interpolated)"),
    "betas": ("P x B", "float32", "shape parameters (one per track)"),
    "world_root_orient": ("P x T x 3", "float32", "root orientation in the world (axis-angle)"),
    "world_transl": ("P x T x 3", "float32", "SMPL translation in the world (metres)"),
    "body_pose": ("P x T x 23 x 3", "float32", "joint rotations relative to their parents (axis-angle)"),
    "world_joints": ("P x T x 24 x 3", "float32", "SMPL joint positions in the world (metres)"),
    "cam_root_orient": ("P x T x 3", "float32", "root orientation in each frame's camera"),
    "cam_transl": ("P x T x 3", "float32", "SMPL translation in each frame's camera (metres)"),
    "lift_world_root_orient": ("P x T x 3", "float32", "root orientation after the world lift, before optimization"),
    "lift_world_transl": ("P x T x 3", "float32", "translation after the world lift, before optimization"),
    "lift_body_pose": ("P x T x 23 x 3", "float32", "joint rotations after the world lift, before optimization"),
    "lift_betas": ("P x B", "float32", "shape parameters after the world lift, before optimization"),
    "lift_world_from_cam": ("T x 4 x 4", "float32", "camera poses of the world lift (metres, its camera scale)"),
    "keypoints_2d": ("P x T x 17 x 3", "float32", "observed COCO-17 keypoints: u, v (pixels), confidence"),
    "contacts": ("P x T x 4", "float32", "contact probability of SMPL joints 7, 8, 10, 11 (ankles, feet)"),
    "ground_normal": ("P x T x 3", "float32", "the person's ground plane n . x + d = 0 in the world: n"),
    "ground_offset": ("P x T", "float32", "the person's ground plane: d (metres)"),
    "reprojection_error": ("P x T", "float32",
                           "mean distance (pixels) between observed keypoints (confidence >= 0.4) and the projected "
                           "final body's keypoints"),
    "left_hand_pose": ("P x T x 15 x 3", "float32",
                       "left hand's finger rotations relative to their parents (axis-angle; SMPL-H/MANO order "
                       "index1-3, middle1-3, pinky1-3, ring1-3, thumb1-3; m3c.body.hands); NaN where no hand "
                       "was fitted"),
    "right_hand_pose": ("P x T x 15 x 3", "float32", "right hand's finger rotations, as left_hand_pose"),
    "hand_keypoints_2d": ("P x T x 2 x 21 x 3", "float32",
                          "observed MediaPipe hand landmarks, left hand then right: u, v (pixels), confidence "
                          "(MediaPipe's order: wrist, thumb CMC, MCP, IP, tip, then index, middle, ring, pinky "
                          "MCP, PIP, DIP, tip); NaN where no hand was found"),
    "world_hand_keypoints": ("P x T x 2 x 21 x 3", "float32",
                             "the fitted hands' 21 points (hand_keypoints_2d's order) in the world (metres); "
                             "NaN where no hand was fitted"),
}


# What held the contacts' ground's tilt (results.json world.ground_tilt_prior), as `m3c info` says it.
TILT_PRIORS = {"scene": "the scene's vertical edges", "people": "the people's upright direction",
               "camera": "the first camera's up direction"}


def _scale_uncertainty(camera: dict) -> str:
    sigma = (camera.get("scale_estimate") or {}).get("sigma")
    return f", +-{100 * sigma:.1f}%" if sigma else ""


def _world_size_warning(camera: dict) -> list[str]:
    """A plain warning when the world's size (the camera scale) is uncertain: sources that disagree or a wide
    estimate (results.json camera.scale_estimate.confidence, m3c.vo.scale.ScaleEstimate)."""
    estimate = camera.get("scale_estimate") or {}
    if estimate.get("confidence") != "low":
        return []
    factor = np.exp(2 * estimate["sigma"])
    text = estimate.get("disagreement") or (f"the camera scale is uncertain by a factor of {factor:.2f} either "
                                            "way (2 sigma), and the world's size with it")
    return [f"warning     the world's size is uncertain: {text}; distances and speeds may be off by that "
            "factor"]


def _rate(video: dict) -> str:
    """The processed frames' rate as the file plays them, and in real time when it is slow motion."""
    slow = video.get("slow_motion", 1.0)
    if slow == 1.0:
        return f"{video['fps']:.3f} fps"
    return f"{video['fps'] / slow:.3f} fps (slow motion x{slow:g}: {video['fps']:.3f} fps of real time)"


def _slow_gait_hint(figures: dict) -> str:
    """A track whose walk or run is confidently slower than people step (m3c.motion.time_scale): the clip may play
    slower than it was filmed (slow motion)."""
    measured = gait_time_scale(figures)
    if measured is not None and measured[0] >= MIN_FACTOR \
            and np.log(measured[0]) > CONFIDENT_SIGMAS * measured[1]:
        what = "a step" if measured[2] == UNCLASSIFIED_GAIT else f"a {measured[2]} step"
        return (f"; {what} at a slow rate: if the video is slow motion (x{measured[0]:.1f}?), give "
                "--slow-motion (then speeds are real time)")
    return ""


def _legs_line(figures: dict) -> str:
    """The legs' figures (m3c.eval.plausibility.leg_figures) in words, with a warning where they look wrong: a knee
    bent most of the time, feet that never swap while the person travels, a pelvis advancing in surges."""
    flex, bent = figures["knee_flex_deg"], figures["knee_bent_fraction"]
    words = [f"knees flexed {flex[0]:.0f} / {flex[1]:.0f} degrees median (left / right), over 45 in "
             f"{100 * bent[0]:.0f}% / {100 * bent[1]:.0f}% of frames"]
    if figures.get("lead_changes") is not None:
        words.append(f"lead foot changed {figures['lead_changes']} times, at most {figures['longest_lead_s']:.1f} s "
                     "apart")
    if figures.get("surge_ratio") is not None:
        words.append(f"fastest second x{figures['surge_ratio']:.1f} the mean speed")
    odd = []
    if max(bent) > 1 / 3:
        odd.append("a knee bent over 45 degrees in over a third of the frames")
    travelling = figures["mean_speed_mps"] > 0.3 and figures["displacement_m"] > 1.0
    if travelling and figures.get("longest_lead_s") is not None and figures["longest_lead_s"] > 2.0:
        odd.append("one foot leads for over 2 s while the person travels")
    if travelling and (figures.get("surge_ratio") or 0) > 2.0:
        odd.append("the person advances in surges")
    if odd:
        words.append("CHECK: " + ", ".join(odd) + " (look at m3c view)")
    return "; ".join(words)


def _time_scale(video: dict) -> list[str]:
    """The slow motion the people's gait says (results.json video.time_scale), when it measured any."""
    estimate = video.get("time_scale")
    if not estimate or estimate.get("log_sigma") is None:
        return []
    n = len(estimate["tracks"])
    figure = (f"x{estimate['measured']:.2f} +-{100 * estimate['log_sigma']:.0f}% from the gait of {n} "
              f"track{'s' * (n > 1)}")
    if estimate["confident"]:
        return [f"time        slow motion likely: {estimate['reason']} ({figure}); give --slow-motion "
                f"{estimate['factor']:.2f} for real-time speeds"]
    if estimate.get("possible"):
        return [f"time        slow motion possible: {estimate['reason']} ({figure}); if the video is slow motion, "
                f"give --slow-motion {estimate['factor']:.2f}"]
    return [f"time        {estimate['reason']} ({figure})"]


def _focal_uncertainty(camera: dict) -> str:
    estimate = camera.get("focal_estimate")
    scene = camera.get("scene")
    if camera.get("intrinsics_source") == "scene" and scene:
        return f" (from the scene's lines: {scene['reason']})"
    if camera.get("intrinsics_source") == "people" and camera.get("feet_focal"):
        return f" ({camera['feet_focal']['message']})"
    if not estimate:
        return ""
    if not estimate["informative"]:
        return " (focal search uninformative: default kept)"
    return f" (focal {estimate['ratio']:.2f} x the image diagonal, log-sigma {estimate['log_sigma']:.3f})"


def _camera_motion(camera: dict) -> str:
    """static (declared), rotation only (the odometry found no translation to trust), still (the focal search saw
    no window move) or moving."""
    if camera["static"]:
        return "static"
    if camera.get("rotation_only"):
        return "still or rotating (the odometry found no translation it could trust; no scale read from it)"
    if (camera.get("focal_estimate") or {}).get("still"):
        return "still (no motion in the focal search's windows)"
    return "moving"


def _odometry_fit(camera: dict) -> str:
    fit = camera.get("odometry_fit")
    if not fit or fit.get("keyframe_rms_px") is None:
        return ""
    if fit.get("runs", 1) > 1 and fit.get("runs_rms_px"):
        others = ", ".join("-" if x is None else f"{x:.2f}"
                           for i, x in enumerate(fit["runs_rms_px"]) if i != fit["kept"])
        return (f" (the best fit of {fit['runs']} runs after {fit['compared_after_frames']} frames: "
                f"{fit['keyframe_rms_px']:.2f} px; the others {others})")
    return f" (fit {fit['keyframe_rms_px']:.2f} px)"


def _hands_line(hands: dict | None) -> list[str]:
    """The hands node's outcome (results.json hands), when the results have one."""
    if not hands:
        return []
    if not hands["enabled"]:
        return [f"hands       none: {hands['reason']}"]
    return [f"hands       {hands['hands_fitted']} hands fitted in {hands['person_frames']} person-frames"]


def json_ready(value):
    """`value` (dicts, lists, numbers) with every NaN/inf float as None: results.json writes a value that is missing
    (a stage that could not evaluate its objective, a figure without data) as null, never as NaN, which JSON lacks."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def schema_markdown() -> str:
    """The README table of results.npz."""
    lines = ["| array | shape | dtype | meaning |", "|---|---|---|---|"]
    for name, (shape, dtype, text) in ARRAYS.items():
        lines.append(f"| `{name}` | {shape or 'scalar'} | {dtype} | {text} |")
    return "\n".join(lines)


def check_arrays(arrays: dict) -> None:
    """Every schema array is present with its dtype family; nothing else is."""
    missing, extra = set(ARRAYS) - set(arrays), set(arrays) - set(ARRAYS)
    if missing or extra:
        raise ValueError(f"results arrays differ from the schema: missing {sorted(missing)}, extra {sorted(extra)}")
    for name, (_, dtype, _) in ARRAYS.items():
        kind = np.asarray(arrays[name]).dtype.kind
        expected = {"str": "U", "bool": "b"}.get(dtype, "i" if dtype.startswith("int") else "f")
        if kind != expected:
            raise ValueError(f"results array {name} has dtype {np.asarray(arrays[name]).dtype}, schema says {dtype}")


RESULT_FILES = ("results.npz", "results.json")
# Every file `m3c run` publishes with the default pipeline, in the order `m3c info` lists them.
PUBLISHED_FILES = RESULT_FILES + ("overlay.mp4", "world.mp4", "camera_trajectory.png")


def load_results(folder: str | Path, check: bool = True) -> tuple[dict, dict]:
    """(summary from results.json, arrays from results.npz) of a run's output folder.

    check: the folder's manifest must vouch for both files (one complete run wrote them and they are unchanged);
    raises m3c.io.manifest.IncompleteResults (a ValueError) naming what is wrong otherwise. check=False reads
    whatever is there."""
    folder = Path(folder)
    json_path, npz_path = folder / "results.json", folder / "results.npz"
    if not json_path.is_file() or not npz_path.is_file():
        raise FileNotFoundError(f"{folder} holds no M3C results (results.json and results.npz); run "
                                f"`m3c run VIDEO --out {folder}` first")
    if check:
        check_complete(folder, RESULT_FILES)
    summary = json.loads(json_path.read_text())
    if summary.get("schema") != SCHEMA:
        raise ValueError(f"{json_path}: schema {summary.get('schema')!r}, this M3C reads {SCHEMA!r}")
    with np.load(npz_path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    return summary, arrays


def describe(folder: str | Path) -> str:
    """A human-readable summary of a result folder (`m3c info`)."""
    folder = Path(folder)
    state = folder_state(folder, PUBLISHED_FILES)
    if state.status == "empty":
        raise FileNotFoundError(f"{folder} holds no M3C results; run `m3c run VIDEO --out {folder}` first")
    if not (folder / "results.json").is_file() or not (folder / "results.npz").is_file():
        return f"{folder}: {state.message}\nstate       {state.status}; no results.npz/results.json here"
    summary, arrays = load_results(folder, check=False)
    video, camera = summary["video"], summary["camera"]
    lines = [f"{folder}: M3C {summary['m3c_version']} results ({summary['schema']})",
             f"state       {state.status}: {state.message}" if not state.complete else
             f"state       complete (run {state.manifest.get('run_key')}, every file checked against "
             f"{MANIFEST})",
             f"video       {video['name']}: {video['width']} x {video['height']}, {_rate(video)}, frames "
             f"{video['frame_range'][0]}..{video['frame_range'][1] - 1} step {video['frame_range'][2]} "
             f"({video['frames']} processed)" + (
                 f"\n            WARNING: only {video['total_frames']} of the {video['frames_in_container']} frames "
                 "its container lists decode (a cut or damaged file)" if video.get("truncated") else ""),
             *_time_scale(video),
             f"body model  {summary['body_model']['name']} ({summary['body_model']['gender']})",
             f"camera      {_camera_motion(camera)}, intrinsics {camera['intrinsics_source']} "
             f"[{', '.join(f'{v:.1f}' for v in camera['intrinsics'])}]{_focal_uncertainty(camera)}, odometry: "
             f"{camera['odometry']}{_odometry_fit(camera)}, scale "
             f"{camera['scale']:.4f} m/unit ({camera['scale_source']}{_scale_uncertainty(camera)})",
             *_world_size_warning(camera),
             f"world       {summary['world']['frame']}; ground: {summary['world']['ground']}"
             + (f" (from the {summary['world']['ground_source']})" if summary["world"].get("ground_source") else "")
             + (f"; its tilt held by {TILT_PRIORS[summary['world']['ground_tilt_prior']]}"
                if summary["world"].get("ground_tilt_prior") in TILT_PRIORS else ""),
             f"lift        {summary['lift']['method']}; optimization: "
             f"{'stopped early' if summary['optimization']['stopped_early'] else 'complete'}"
             if summary["optimization"]["optimized"] else f"lift        {summary['lift']['method']}; no optimization",
             *_hands_line(summary.get("hands")),
             f"tracks      {len(summary['tracks'])}"]
    for track in summary["tracks"]:
        err = track["mean_reprojection_error_px"]
        lines.append(f"  id {track['id']:>3}: frames {track['first_frame']}..{track['last_frame']} "
                     f"({track['visible_frames']}/{track['frames']} detected), reprojection "
                     f"{'n/a' if err is None else f'{err:.1f} px'}, path {track['path_length_m']:.2f} m")
        lean = track.get("lean")
        if lean and lean.get("refit"):
            lines.append(f"         leaned {lean['lean_before']:+.1f} degrees towards the camera against the scene's "
                         f"vertical: re-fitted to {lean['lean_after']:+.1f} (depth x{lean['depth_ratio']:.3f})")
        figures = track.get("plausibility")
        if figures:
            ratio = figures["path_ratio"]
            lines.append(f"         speed {figures['mean_speed_mps']:.2f} m/s mean, {figures['peak_speed_mps']:.2f} "
                         f"peak; path {figures['path_length_m']:.2f} m for {figures['displacement_m']:.2f} m "
                         f"displacement{'' if ratio is None else f' (x{ratio:.1f})'}; slower foot "
                         f"{figures['slow_foot_speed_mps']:.2f} m/s; below ground "
                         f"{100 * figures['below_ground_fraction']:.0f}% of frames, "
                         f"{100 * figures['penetration_m']:.0f} cm deep")
            if figures.get("implausible_speed"):
                lines.append(f"         IMPLAUSIBLE: {figures['sustained_speed_mps']:.1f} m/s held for a second, faster "
                             "than any person moves (12 m/s): the camera scale, the intrinsics or the frame rate "
                             "is wrong (--intrinsics, --hfov, --fps)")
            if figures.get("step_rate_spm") is not None:
                lines.append(f"         gait {figures['step_rate_spm']:.0f} steps/min, "
                             f"{figures['step_length_m']:.2f} m a step ({figures['step_length_legs']:.2f} leg "
                             f"lengths){_slow_gait_hint(figures)}")
            if figures.get("knee_flex_deg") is not None:
                lines.append(f"         legs {_legs_line(figures)}")
    for stage in summary["optimization"]["stages"]:
        parts = stage.get("parts", 1)  # runs before parts were reported have none
        lines.append(f"  stage {stage['name']:<14} {stage['status']:<10} {stage['iterations']:>3} it  objective "
                     f"{stage['objective_before']:.4g} -> {stage['objective_after']:.4g}"
                     + (f"  ({parts} problems)" if parts > 1 else ""))
    files = [name for name in PUBLISHED_FILES if (folder / name).is_file()]
    vouched = set(state.files)
    lines.append(f"files       {', '.join(f if f in vouched or not state.complete else f + ' (stray)' for f in files)}")
    lines.append(f"arrays      {len(arrays)} in results.npz (schema in results.json['arrays'])")
    return "\n".join(lines)
