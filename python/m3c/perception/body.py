"""Camera-local bodies without HMR 2.0: the body model fitted per frame to 2D keypoints (and MediaPipe's metric
3D landmarks) in C++ (cpp/fit), each frame of a track warm-started from the previous one.

Outputs are in the camera frame (OpenCV axes, metres): root_orient rotates the body model's frame into the
camera's, transl is the body model's translation, so joints_in_cam = model.joints(pose, betas, transl).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from m3c import _core
from m3c.body import BodyModel, default_body_model
from m3c.body.joint_names import COCO17_SOURCES
from m3c.perception.interfaces import BodyEstimator
from m3c.perception.registry import register
from m3c.perception.types import FOOT_KEYPOINT_NAMES, NUM_COCO, NUM_WITH_FEET

NAME = "fit"
HIPS = (11, 12)  # COCO-17 hips: the origin of MediaPipe's metric landmarks
SHOULDERS = (5, 6)
RESTART_GAP = 5  # a track's fit starts cold after more than this many frames without it


def cold_starts(frame_ids, restart_gap: int = RESTART_GAP) -> np.ndarray:
    """(n,) bool: the frames of a track (frame_ids, increasing) whose fit starts cold, the first and every one
    after more than restart_gap frames without the person (fit_bodies' restart)."""
    frame_ids = np.asarray(frame_ids)
    return np.concatenate([[True], np.diff(frame_ids) > restart_gap + 1])[:len(frame_ids)]


def keypoint_regressor(model: BodyModel, num_keypoints: int = NUM_COCO):
    """The body's keypoints for 17 (COCO-17) or 21 (COCO-17 then FOOT_KEYPOINT_NAMES, as vertices) rows."""
    if num_keypoints == NUM_COCO:
        return model.coco17_regressor()
    if num_keypoints != NUM_WITH_FEET:
        raise ValueError(f"keypoints must have 17 (COCO-17) or 21 (COCO-17 + feet) rows, got {num_keypoints}")
    if model.num_joints != 24:
        raise ValueError(f"COCO-17 needs the SMPL 24-joint layout, this model has {model.num_joints} joints")
    table = model.keypoint_vertex_ids()
    vw = np.zeros((NUM_WITH_FEET, model.num_vertices))
    jw = np.zeros((NUM_WITH_FEET, model.num_joints))
    sources = list(COCO17_SOURCES) + [("vertex", name) for name in FOOT_KEYPOINT_NAMES]
    for k, (kind, key) in enumerate(sources):
        if kind == "vertex":
            vw[k, table[key]] = 1.0
        else:
            jw[k, key] = 1.0
    return model.regressor(vw, jw)


_FIT = _core.BodyFitOptions()  # the defaults (cpp/fit/frame_fit.h), read from the core, never copied


@dataclass
class BodyFitConfig:
    """Weights and settings of the per-frame fit (defaults = cpp/fit's FitOptions; see fit/frame_fit.h).

    Reprojection costs are in pixels (Geman-McClure with robust_sigma_px), the 3D term in metres, priors in
    radians and shape units; a weight w on a term means a residual of size 1/sqrt(w) costs as much as 1 px.
    """

    robust_sigma_px: float = _FIT.robust_sigma_px
    min_confidence: float = _FIT.min_confidence
    min_keypoints: int = _FIT.min_keypoints
    keypoints3d_weight: float = _FIT.keypoints3d_weight
    keypoints3d_sigma: float = _FIT.keypoints3d_sigma
    pose_prior_weight: float = _FIT.pose_prior_weight
    vposer_weight: float = _FIT.vposer_weight
    shape_prior_weight: float = _FIT.shape_prior_weight
    temporal_pose_weight: float = _FIT.temporal_pose_weight
    temporal_betas_weight: float = _FIT.temporal_betas_weight
    temporal_transl_weight: float = _FIT.temporal_transl_weight
    optimize_betas: bool = _FIT.optimize_betas
    min_depth: float = _FIT.min_depth
    max_iterations: int = _FIT.max_iterations
    reinit_error_px: float = _FIT.reinit_error_px
    max_turn_from_3d_deg: float = _FIT.max_turn_from_3d_deg
    max_limb_from_3d_m: float = _FIT.max_limb_from_3d_m

    def to_core(self) -> "_core.BodyFitOptions":
        options = _core.BodyFitOptions()
        for f in fields(self):
            setattr(options, f.name, getattr(self, f.name))
        return options


@dataclass
class BodyFits:
    """Per-frame fits of one track (n frames): transl (n, 3) camera frame metres, root_orient (n, 3), body_pose
    (n, J-1, 3), betas (n, B), reprojection_error_px (n) mean over the keypoints used, keypoint_error_px (n, K),
    num_keypoints (n), warm_started (n), status (n strings: "ok" or "too_few_keypoints"), valid (n) = ok."""

    transl: np.ndarray
    root_orient: np.ndarray
    body_pose: np.ndarray
    betas: np.ndarray
    reprojection_error_px: np.ndarray
    keypoint_error_px: np.ndarray
    num_keypoints: np.ndarray
    warm_started: np.ndarray
    status: list

    @property
    def valid(self) -> np.ndarray:
        return np.array([s == "ok" for s in self.status], dtype=bool)

    @property
    def pose(self) -> np.ndarray:
        """(n, J, 3) axis-angle, root first."""
        return np.concatenate([self.root_orient[:, None], self.body_pose], axis=1)


def fit_bodies(model: BodyModel, keypoints, intrinsics, keypoints3d=None, restart=None,
               config: BodyFitConfig | None = None, regressor=None, times=None, pose_prior=None) -> BodyFits:
    """Fits the body to one track's frames in order (frame i warm-started from the last good fit unless
    restart[i], its translation predicted at constant velocity over `times`).

    keypoints: (n, K, 3) u, v, confidence with K = 17 (COCO-17) or 21 (COCO-17 + feet, see types);
    intrinsics: (4,) or (n, 4) fx, fy, cx, cy; keypoints3d: None or (n, K, 4) x, y, z metres (camera axes, any
    origin) and confidence; restart: None or (n,) bool; times: None (consecutive frames) or (n,) increasing frame
    numbers or seconds. regressor: the body's keypoints the rows correspond to (default keypoint_regressor(K)).
    pose_prior: None or a learned pose prior (m3c.nn.VPoser) weighted by config.vposer_weight.
    """
    config = config or BodyFitConfig()
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if keypoints.ndim != 3:
        raise ValueError(f"keypoints must have shape (n, K, 3), got {keypoints.shape}")
    regressor = regressor or keypoint_regressor(model, keypoints.shape[1])
    out = _core.fit_body_sequence(model._core, regressor, keypoints,
                                  np.asarray(intrinsics, dtype=np.float64),
                                  None if keypoints3d is None else np.asarray(keypoints3d, dtype=np.float64),
                                  None if restart is None else np.asarray(restart, dtype=bool),
                                  None if times is None else np.asarray(times, dtype=np.float64), config.to_core(),
                                  None if pose_prior is None else pose_prior._core)
    return BodyFits(out["transl"], out["root_orient"], out["body_pose"], out["betas"], out["reprojection_error_px"],
                    out["keypoint_error_px"], out["num_keypoints"], out["warm_started"], list(out["status"]))


# The fit's learned pose prior by default. Off: on the default video set (seed 0) M3C's shipped prior at
# vposer_weight 2 lowered PA-MPJPE on 5 of 7 sequences (83.1 -> 77.4 mm overall) but moved the camera scale the
# people give on the follow and tracking cameras (W-MPJPE100 295 -> 453 and 383 mm; 209 -> 240 overall); see
# docs/notes/learned-models.md.
DEFAULT_POSE_PRIOR = "none"


@register("body", NAME)
class FitBodyEstimator(BodyEstimator):
    """The per-frame fit with a body model file (default: the shipped open model) and BodyFitConfig options.
    pose_prior: the learned pose prior in the fit (SMPLify-style): "shipped" (M3C's own, m3c.models.weights;
    non-commercial), "none", or an exported vposer.safetensors (python -m m3c.models.export)."""

    def __init__(self, model_path: str | None = None, pose_prior: str = DEFAULT_POSE_PRIOR, **options):
        self.model = BodyModel.from_file(model_path, smpl_layout=True) if model_path else default_body_model()
        self.config = BodyFitConfig(**options)
        self.pose_prior = load_pose_prior(pose_prior)

    def fit_track(self, keypoints, keypoints3d, intrinsics, restart=None, times=None) -> BodyFits:
        return fit_bodies(self.model, keypoints, intrinsics, keypoints3d, restart, self.config, None, times,
                          self.pose_prior)


def pose_prior_file(setting: str | None) -> Path | None:
    """The exported weights a pose_prior setting names: "shipped" -> M3C's own, exported once into the cache;
    "none" / None -> None; else the path, which must exist."""
    if setting in (None, "none"):
        return None
    if setting == "shipped":
        from m3c.models.weights import shipped_vposer_runtime

        return shipped_vposer_runtime()
    path = Path(setting).expanduser()
    if not path.is_file():
        raise ValueError(f"pose_prior: {path} does not exist; give 'shipped', 'none' or an exported "
                         "vposer.safetensors (python -m m3c.models.export --vposer ... --out DIR)")
    return path


def load_pose_prior(setting: str | None):
    from m3c.nn import VPoser

    path = pose_prior_file(setting)
    return None if path is None else VPoser(path)


def rough_location(keypoints: np.ndarray, keypoints3d: np.ndarray | None, intrinsics,
                   min_confidence: float = 0.5, torso_length: float = 0.5) -> np.ndarray | None:
    """A quick camera-frame location (3,) of a person's hip centre, for tracking before any fit: the depth at
    which the metric 3D keypoints' spread (or, without them, a nominal torso_length in metres from shoulder to
    hip centre) matches the 2D keypoints' spread. None when the hips are not seen."""
    fx, fy, cx, cy = np.asarray(intrinsics, dtype=np.float64)
    k = np.asarray(keypoints, dtype=np.float64)
    good = k[:, 2] >= min_confidence
    if not good[list(HIPS)].all():
        return None
    hip = k[list(HIPS), :2].mean(axis=0)
    f = 0.5 * (fx + fy)
    depth = None
    if keypoints3d is not None:
        q = np.asarray(keypoints3d, dtype=np.float64)
        use = good & (q[:, 3] >= min_confidence)
        if use.sum() >= 4:
            q_hip = q[list(HIPS), :3].mean(axis=0)
            spread3 = np.linalg.norm(q[use, :2] - q_hip[:2], axis=1).sum()
            spread2 = np.linalg.norm(k[use, :2] - hip, axis=1).sum()
            if spread2 > 1e-6 and spread3 > 1e-6:
                depth = f * spread3 / spread2
    if depth is None and good[list(SHOULDERS)].all():
        length = np.linalg.norm(k[list(SHOULDERS), :2].mean(axis=0) - hip)
        if length > 1e-6:
            depth = f * torso_length / length
    if depth is None:
        return None
    return np.array([(hip[0] - cx) / fx * depth, (hip[1] - cy) / fy * depth, depth])
