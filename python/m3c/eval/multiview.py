"""A real-footage reference for single-view results: one person filmed by calibrated static cameras, with 3D
keypoints triangulated from all the views (Pose2Sim's demo, examples/pose2sim_single_person).

M3C runs on each camera's video alone; each result is compared, in the calibrated world, with what the
calibration and the triangulation say:
  camera height above the floor and camera tilt to gravity (M3C's world: y up, ground y = 0);
  the ground at the person's feet: the distance of the triangulated feet to M3C's ground against the truth;
  MPJPE (pelvis-aligned) and PA-MPJPE in the camera frame on the 13 triangulated keypoints that map onto SMPL
  joints (hips, knees, ankles, shoulders, elbows, wrists, neck), and the pelvis depth error;
  the disagreement of the single-view results with each other: their joints taken into the calibrated world by
  the true camera poses, mean pairwise distance per frame.
The triangulation is not marker ground truth (OpenPose keypoints, a few centimetres of error) and OpenPose's hips
are not SMPL's hip joints, so the joint errors have a floor of a few centimetres.
"""

from __future__ import annotations

import logging
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m3c.eval import metrics as M

LOG = logging.getLogger("m3c.eval.multiview")
# TRC keypoint name -> SMPL joint index.
TRC_TO_SMPL = {
    "LHip": 1,
    "RHip": 2,
    "LKnee": 4,
    "RKnee": 5,
    "LAnkle": 7,
    "RAnkle": 8,
    "Neck": 12,
    "LShoulder": 16,
    "RShoulder": 17,
    "LElbow": 18,
    "RElbow": 19,
    "LWrist": 20,
    "RWrist": 21,
}
FEET = ("LHeel", "RHeel", "LBigToe", "RBigToe")
PELVIS = (0, 1)  # LHip, RHip in TRC_TO_SMPL's order


@dataclass
class CalibratedCamera:
    name: str
    K: np.ndarray  # (3, 3)
    distortion: np.ndarray  # (4,) k1, k2, p1, p2
    cam_from_world: np.ndarray  # (4, 4), metres, world Z up
    size: tuple  # (W, H) per the calibration

    @property
    def intrinsics(self) -> np.ndarray:
        return np.array([self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]])

    @property
    def centre(self) -> np.ndarray:
        R, t = self.cam_from_world[:3, :3], self.cam_from_world[:3, 3]
        return -R.T @ t


@dataclass
class MultiviewSequence:
    folder: Path
    cameras: list[CalibratedCamera]
    videos: dict  # camera name -> video path
    fps: float
    names: list[str]  # TRC keypoint names
    keypoints: np.ndarray  # (T, K, 3) calibrated world (Z up), metres

    def joints(self) -> np.ndarray:
        """(T, 13, 3) the keypoints that map onto SMPL joints, in TRC_TO_SMPL's order."""
        return self.keypoints[:, [self.names.index(n) for n in TRC_TO_SMPL]]

    def feet(self) -> np.ndarray:
        """(T, 3) the mean of the heels and big toes."""
        return self.keypoints[:, [self.names.index(n) for n in FEET]].mean(axis=1)


def _toml(path: Path) -> dict:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        try:
            import tomli as tomllib
        except ImportError as err:
            raise ImportError(
                "reading the calibration needs Python 3.11, or `pip install tomli` on 3.10"
            ) from err
    return tomllib.loads(path.read_text())


def read_trc(path: str | Path) -> tuple[list[str], np.ndarray, float]:
    """(keypoint names, (T, K, 3) in the TRC's axes, frame rate) of a .trc file."""
    lines = Path(path).read_text().splitlines()
    if len(lines) < 6 or not lines[0].startswith("PathFileType"):
        raise ValueError(f"{path}: not a TRC file (no PathFileType header)")
    header = dict(zip(lines[1].split("\t"), lines[2].split("\t")))
    if header.get("Units", "m") != "m":
        raise ValueError(f"{path}: units {header.get('Units')!r}, expected metres")
    names = [n for n in lines[3].split("\t")[2:] if n.strip()]
    rows = [
        np.array(line.split("\t")[2 : 2 + 3 * len(names)], dtype=np.float64)
        for line in lines[5:]
        if line.strip()
    ]
    return names, np.stack(rows).reshape(len(rows), len(names), 3), float(header["DataRate"])


def load_multiview(folder: str | Path) -> MultiviewSequence:
    """The Pose2Sim layout: Calib_qualisys.toml, one .trc, videos/<camera>.mp4 (cam_01 -> cam01.mp4)."""
    import cv2

    folder = Path(folder)
    calib, trcs = folder / "Calib_qualisys.toml", sorted(folder.glob("*.trc"))
    if not calib.is_file() or not trcs:
        raise FileNotFoundError(
            f"{folder} is not a multiview reference folder (needs Calib_qualisys.toml, a .trc "
            "and videos/); the repository ships one in examples/pose2sim_single_person"
        )
    cameras, videos = [], {}
    for name, entry in _toml(calib).items():
        if not isinstance(entry, dict) or "matrix" not in entry:
            continue
        R, _ = cv2.Rodrigues(np.asarray(entry["rotation"], dtype=np.float64))
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R, np.asarray(entry["translation"], dtype=np.float64)
        cam = CalibratedCamera(
            name,
            np.asarray(entry["matrix"], dtype=np.float64),
            np.asarray(entry["distortions"], dtype=np.float64),
            pose,
            tuple(int(v) for v in entry["size"]),
        )
        video = folder / "videos" / f"{name.replace('_', '')}.mp4"
        if not video.is_file():
            raise FileNotFoundError(f"no video for camera {name}: expected {video}")
        cameras.append(cam)
        videos[name] = video
    names, trc, fps = read_trc(trcs[0])
    world = trc[..., [2, 0, 1]]  # calibration world (Z up) = (trc Z, trc X, trc Y)
    return MultiviewSequence(folder, cameras, videos, fps, names, world)


@dataclass
class ViewScore:
    camera: str
    folder: str = ""
    seconds: float = 0.0
    frames: int = 0
    values: dict = field(default_factory=dict)
    joints_in_world: np.ndarray | None = None  # (T, 13, 3) NaN where not tracked
    error: str = ""


def _to_cam(points, cam_from_world):
    return points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]


def score_view(model, seq: MultiviewSequence, cam: CalibratedCamera, arrays: dict) -> ViewScore:
    """One camera's results against the calibration and the triangulation."""
    score = ViewScore(cam.name)
    T = seq.keypoints.shape[0]
    if len(arrays["track_ids"]) == 0:
        raise ValueError(f"{cam.name}: the run found no person")
    p = int(np.argmax(arrays["valid"].sum(axis=1)))  # the longest track: the person
    t = np.flatnonzero(arrays["valid"][p])
    frames = arrays["frame_ids"][t]
    keep = frames < T
    t, frames = t[keep], frames[keep]
    world_from_cam = arrays["world_from_cam"][t].astype(np.float64)
    pred_world = arrays["world_joints"][p, t].astype(np.float64)[:, list(TRC_TO_SMPL.values())]
    cam_from_pred = np.linalg.inv(world_from_cam)
    pred_cam = np.einsum("nij,nkj->nki", cam_from_pred[:, :3, :3], pred_world) + cam_from_pred[:, None, :3, 3]
    true_cam = _to_cam(seq.joints()[frames], cam.cam_from_world)
    # Camera height and tilt: the true floor is Z = 0 (up e_z); M3C's ground is y = 0 (up e_y).
    up_true = cam.cam_from_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
    up_pred = world_from_cam[:, 1, :3]  # world y in camera coordinates
    height_true, height_pred = cam.centre[2], world_from_cam[:, 1, 3]
    cos = np.clip(up_pred @ up_true / np.linalg.norm(up_pred, axis=-1), -1.0, 1.0)
    # The ground at the feet: distance of the triangulated feet (camera frame) to each ground plane.
    feet_cam = _to_cam(seq.feet()[frames], cam.cam_from_world)
    feet_to_true = feet_cam @ up_true + height_true
    feet_to_pred = (feet_cam * up_pred).sum(-1) / np.linalg.norm(up_pred, axis=-1) + height_pred
    pelvis_true, pelvis_pred = M.pelvis_of(true_cam, PELVIS), M.pelvis_of(pred_cam, PELVIS)
    score.values = {
        "camera_height_m": float(height_true),
        "camera_height_pred_m": float(np.mean(height_pred)),
        "camera_height_error_m": float(np.mean(np.abs(height_pred - height_true))),
        "tilt_error_deg": float(np.degrees(np.arccos(cos)).mean()),
        "ground_at_feet_error_m": float(np.mean(np.abs(feet_to_pred - feet_to_true))),
        "mpjpe": float(M.mpjpe(pred_cam, true_cam, PELVIS).mean()),
        "pa_mpjpe": float(M.pa_mpjpe(pred_cam, true_cam).mean()),
        "pelvis_depth_error_m": float(np.mean(np.abs(pelvis_pred[:, 2] - pelvis_true[:, 2]))),
        "frames": len(frames),
        "tracks": len(arrays["track_ids"]),
    }
    joints = np.full((T, len(TRC_TO_SMPL), 3), np.nan)
    world_from_true = np.linalg.inv(cam.cam_from_world)
    joints[frames] = pred_cam @ world_from_true[:3, :3].T + world_from_true[:3, 3]
    score.joints_in_world = joints
    score.frames = len(frames)
    return score


def disagreement_mm(views: list[ViewScore]) -> float | None:
    """Mean pairwise distance (mm) between the single-view results' joints in the calibrated world, over the
    frames and joints that both views of a pair have."""
    distances = []
    usable = [v for v in views if v.joints_in_world is not None]
    for a in range(len(usable)):
        for b in range(a + 1, len(usable)):
            d = np.linalg.norm(usable[a].joints_in_world - usable[b].joints_in_world, axis=-1)
            distances.append(d[np.isfinite(d)])
    values = np.concatenate(distances) if distances else np.zeros(0)
    return float(values.mean() * 1000.0) if len(values) else None


@dataclass
class MultiviewReport:
    folder: str
    views: list[ViewScore]
    disagreement_mm: float | None
    known_intrinsics: bool
    seconds: float

    def text(self) -> str:
        cols = [
            ("Camera", None, 8, 0),
            ("Height m", "camera_height_m", 9, 2),
            ("M3C m", "camera_height_pred_m", 7, 2),
            ("Height err", "camera_height_error_m", 11, 2),
            ("Tilt°", "tilt_error_deg", 7, 1),
            ("Ground@feet m", "ground_at_feet_error_m", 14, 2),
            ("MPJPE", "mpjpe", 7, 0),
            ("PA-MPJPE", "pa_mpjpe", 9, 0),
            ("Depth m", "pelvis_depth_error_m", 8, 2),
            ("Frames", "frames", 7, 0),
        ]
        head = "".join(t.rjust(w) if key else t.ljust(w) for t, key, w, _ in cols)
        lines = [
            f"M3C multiview reference: {self.folder}; each camera's video alone, "
            f"{'calibrated' if self.known_intrinsics else 'default (uncalibrated)'} intrinsics; mm unless "
            "stated; truth: calibration and triangulated keypoints (13 joints).",
            "",
            head,
            "-" * len(head),
        ]
        for v in self.views:
            if v.error:
                lines.append(v.camera.ljust(8) + f"  FAILED: {v.error.splitlines()[0]}")
                continue
            lines.append(
                "".join(
                    v.camera.ljust(w) if key is None else (f"{v.values[key]:.{d}f}").rjust(w)
                    for _, key, w, d in cols
                )
            )
        lines += [
            "",
            f"disagreement of the single-view results in the calibrated world: "
            f"{'-' if self.disagreement_mm is None else f'{self.disagreement_mm:.0f}'} mm "
            f"(mean pairwise joint distance); time {self.seconds:.0f} s",
        ]
        return "\n".join(lines)

    def summary(self) -> dict:
        return {
            "folder": self.folder,
            "known_intrinsics": self.known_intrinsics,
            "seconds": self.seconds,
            "disagreement_mm": self.disagreement_mm,
            "views": [
                {
                    "camera": v.camera,
                    "folder": v.folder,
                    "seconds": v.seconds,
                    "error": v.error or None,
                    **v.values,
                }
                for v in self.views
            ],
        }


def run_multiview(
    model,
    folder: str | Path,
    out_dir: str | Path,
    pipeline_config=None,
    overrides=(),
    known_intrinsics: bool = False,
    cameras=None,
    log=None,
    show_progress: bool = True,
) -> MultiviewReport:
    """Runs M3C on each camera's video (cached under out_dir/<camera>) and scores it; a failed camera is
    reported and the others go on."""
    from m3c.io.results import load_results
    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline import PipelineConfig, Runner, parse_override

    register_builtin_nodes()
    seq = load_multiview(folder)
    base = PipelineConfig.from_yaml(Path(pipeline_config)) if pipeline_config else PipelineConfig.default()
    start = time.perf_counter()
    views = []
    for cam in seq.cameras:
        if cameras and cam.name not in cameras:
            continue
        score = ViewScore(cam.name)
        try:
            settings = dict(parse_override(item) for item in overrides)
            if known_intrinsics:
                settings["camera.intrinsics"] = [float(v) for v in cam.intrinsics]
            config = base.with_overrides(settings) if settings else base
            run_dir = Path(out_dir) / cam.name
            t0 = time.perf_counter()
            Runner(config, run_dir, {"video": seq.videos[cam.name]}, show_progress=show_progress).run(
                ["results"]
            )
            _, arrays = load_results(run_dir)
            score = score_view(model, seq, cam, arrays)
            score.folder, score.seconds = str(run_dir), time.perf_counter() - t0
            if log:
                log(
                    f"{cam.name}: camera height {score.values['camera_height_pred_m']:.2f} m (true "
                    f"{score.values['camera_height_m']:.2f}), MPJPE {score.values['mpjpe']:.0f} mm"
                )
        except KeyboardInterrupt:
            raise
        except Exception as err:  # one camera failing does not stop the others
            score.error = f"{type(err).__name__}: {err}\n{traceback.format_exc()}"
            if log:
                log(f"{cam.name}: FAILED: {type(err).__name__}: {err}")
        views.append(score)
    return MultiviewReport(
        str(folder), views, disagreement_mm(views), known_intrinsics, time.perf_counter() - start
    )
