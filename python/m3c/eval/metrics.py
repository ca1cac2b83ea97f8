"""The field's motion-capture metrics, written from their definitions (thesis 5.2.1; EMDB/WHAM/GVHMR for the
world-frame ones). Inputs are metres (joints, vertices, camera centres) and frames; outputs are per-frame
arrays so that callers can average over frames of many tracks, as the peers do.

Units of the outputs:
  MPJPE, PA-MPJPE, PVE, W-MPJPE100, WA-MPJPE100, foot sliding, ATE, RPE translation: millimetres
  acceleration error: m/s^2 (metres per frame^2 times fps^2, the thesis's and WHAM's convention)
  jitter: m/s^3 (tables print it in units of 10 m/s^3, as EMDB/WHAM/GVHMR do)
  RTE: percent of the ground-truth path length; RPE rotation: degrees

All position errors are Euclidean distances (the thesis's equations 5.1-5.3 write a square, but its numbers
and every peer's code are mean distances in mm).
"""

from __future__ import annotations

import numpy as np

M_TO_MM = 1000.0
SEGMENT_FRAMES = 100  # W-MPJPE100 / WA-MPJPE100 segment length (EMDB protocol)
FOOT_CONTACT_SPEED = 0.01  # ground-truth foot vertex motion below 1 cm per frame counts as contact (GVHMR)


def _points(name: str, value, ndim: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape[-1:] != (3,) or (ndim is not None and arr.ndim != ndim):
        want = "(..., 3)" if ndim is None else "(" + ", ".join(["n", "J"][: ndim - 1]) + ", 3)"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf values")
    return arr


def _same_shape(pred: np.ndarray, gt: np.ndarray) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"prediction {pred.shape} and ground truth {gt.shape} must have the same shape; trim both "
                         "tracks to their common frames first (m3c.eval.matching.common_frames)")


# Alignment --------------------------------------------------------------------------------------------------
def umeyama(source, target, with_scale: bool = True):
    """The similarity (or, without scale, rigid) transform that best maps `source` onto `target` in least
    squares: target ~ s R source + t (Umeyama 1991). source, target: (..., N, 3), batched over leading axes.
    Returns (s (...), R (..., 3, 3), t (..., 3))."""
    src = _points("source", source)
    dst = _points("target", target)
    _same_shape(src, dst)
    if src.ndim < 2 or src.shape[-2] < 1:
        raise ValueError(f"umeyama needs (..., N, 3) point sets with N >= 1, got {src.shape}")
    mu_s = src.mean(axis=-2)
    mu_t = dst.mean(axis=-2)
    xs = src - mu_s[..., None, :]
    xt = dst - mu_t[..., None, :]
    n = src.shape[-2]
    cov = np.swapaxes(xt, -1, -2) @ xs / n  # Sigma_ts, (..., 3, 3)
    U, D, Vt = np.linalg.svd(cov)
    # Reflection guard: flip the weakest axis when U Vt is improper.
    sign = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    sign = np.where(sign == 0, 1.0, sign)
    S = np.ones(D.shape)
    S[..., 2] = sign
    R = (U * S[..., None, :]) @ Vt
    if with_scale:
        var_s = (xs ** 2).sum(axis=(-1, -2)) / n
        if np.any(var_s <= 1e-20):
            raise ValueError("similarity alignment of a point set with no spread (all points equal): the scale "
                             "is undefined")
        s = (D * S).sum(axis=-1) / var_s
    else:
        s = np.ones(D.shape[:-1])
    t = mu_t - s[..., None] * np.einsum("...ij,...j->...i", R, mu_s)
    return s, R, t


def apply_similarity(s, R, t, points) -> np.ndarray:
    """s R x + t for points (..., N, 3) with (s, R, t) batched over the leading axes (or broadcast)."""
    s = np.asarray(s, dtype=np.float64)
    return s[..., None, None] * np.einsum("...ij,...nj->...ni", R, points) + np.asarray(t)[..., None, :]


def procrustes_align(pred, gt) -> np.ndarray:
    """pred (n, J, 3) aligned to gt per frame with a similarity transform (PA-MPJPE's alignment)."""
    pred = _points("pred", pred, 3)
    gt = _points("gt", gt, 3)
    _same_shape(pred, gt)
    return apply_similarity(*umeyama(pred, gt), pred)


def pelvis_of(joints, pelvis) -> np.ndarray:
    """Pelvis (n, 3): the mean of the joints with indices `pelvis` (the hips; one index for a pelvis
    joint)."""
    return np.asarray(joints)[:, list(pelvis)].mean(axis=1)


def _per_point_error_mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=-1).mean(axis=-1) * M_TO_MM


# Camera-frame (pose) metrics --------------------------------------------------------------------------------
def mpjpe(pred_joints, gt_joints, pelvis=(0,)) -> np.ndarray:
    """Mean per-joint position error after aligning each frame's pelvis (mean of joints `pelvis`), mm per
    frame."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    _same_shape(pred, gt)
    pred = pred - pelvis_of(pred, pelvis)[:, None]
    gt = gt - pelvis_of(gt, pelvis)[:, None]
    return _per_point_error_mm(pred, gt)


def pa_mpjpe(pred_joints, gt_joints) -> np.ndarray:
    """MPJPE after a per-frame similarity (Procrustes) alignment of the prediction to the ground truth, mm."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    return _per_point_error_mm(procrustes_align(pred, gt), gt)


def pa_joint_errors(pred_joints, gt_joints) -> np.ndarray:
    """Each joint's error after pa_mpjpe's per-frame alignment, mm (frames, J)."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    return np.linalg.norm(procrustes_align(pred, gt) - gt, axis=-1) * M_TO_MM


def pve(pred_vertices, gt_vertices, pred_joints, gt_joints, pelvis=(0,)) -> np.ndarray:
    """Mean per-vertex error after aligning each frame's pelvis (from the joints), mm per frame."""
    pv = _points("pred_vertices", pred_vertices, 3)
    gv = _points("gt_vertices", gt_vertices, 3)
    _same_shape(pv, gv)
    pj = _points("pred_joints", pred_joints, 3)
    gj = _points("gt_joints", gt_joints, 3)
    _same_shape(pj, gj)
    if len(pv) != len(pj):
        raise ValueError(f"vertices ({len(pv)} frames) and joints ({len(pj)} frames) must cover the same frames")
    return _per_point_error_mm(pv - pelvis_of(pj, pelvis)[:, None], gv - pelvis_of(gj, pelvis)[:, None])


def accel_error(pred_joints, gt_joints, fps: float, pelvis=(0,), valid=None) -> np.ndarray:
    """Acceleration error (Kanazawa et al.): |a_pred - a_gt| averaged over joints, with
    a_t = x_{t-1} - 2 x_t + x_{t+1} of pelvis-aligned joints, times fps^2: m/s^2, one value per interior frame
    (n - 2).
    valid (n,) bool: an interior frame whose stencil touches an invalid frame is dropped."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    _same_shape(pred, gt)
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if len(pred) < 3:
        raise ValueError(f"acceleration needs at least 3 frames, got {len(pred)}")
    pred = pred - pelvis_of(pred, pelvis)[:, None]
    gt = gt - pelvis_of(gt, pelvis)[:, None]
    a_pred = pred[:-2] - 2 * pred[1:-1] + pred[2:]
    a_gt = gt[:-2] - 2 * gt[1:-1] + gt[2:]
    err = np.linalg.norm(a_pred - a_gt, axis=-1).mean(axis=-1) * fps ** 2
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != (len(pred),):
            raise ValueError(f"valid must have shape ({len(pred)},), got {valid.shape}")
        err = err[valid[:-2] & valid[1:-1] & valid[2:]]
    return err


# World-frame metrics ----------------------------------------------------------------------------------------
def _segments(n: int, length: int):
    if length < 1:
        raise ValueError(f"segment length must be >= 1, got {length}")
    return [(s, min(n, s + length)) for s in range(0, n, length)]


def w_mpjpe(pred_joints, gt_joints, segment: int = SEGMENT_FRAMES) -> np.ndarray:
    """W-MPJPE100: world joints cut into segments of `segment` frames; each segment's prediction is aligned to
    the ground truth by the similarity transform fitted on its first two frames' joints only; mm per frame."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    _same_shape(pred, gt)
    out = []
    for a, b in _segments(len(pred), segment):
        head = slice(a, min(a + 2, b))
        s, R, t = umeyama(pred[head].reshape(-1, 3), gt[head].reshape(-1, 3))
        out.append(_per_point_error_mm(apply_similarity(s, R, t, pred[a:b]), gt[a:b]))
    return np.concatenate(out)


def wa_mpjpe(pred_joints, gt_joints, segment: int = SEGMENT_FRAMES) -> np.ndarray:
    """WA-MPJPE100: as W-MPJPE100 but each segment is aligned with the similarity fitted on all its joints;
    mm."""
    pred = _points("pred_joints", pred_joints, 3)
    gt = _points("gt_joints", gt_joints, 3)
    _same_shape(pred, gt)
    out = []
    for a, b in _segments(len(pred), segment):
        s, R, t = umeyama(pred[a:b].reshape(-1, 3), gt[a:b].reshape(-1, 3))
        out.append(_per_point_error_mm(apply_similarity(s, R, t, pred[a:b]), gt[a:b]))
    return np.concatenate(out)


def rte(pred_root, gt_root) -> np.ndarray:
    """Root translation error: the predicted root path rigidly aligned (no scale) to the ground truth over the
    whole sequence, the per-frame distance divided by the ground truth's path length; percent per frame."""
    pred = _points("pred_root", pred_root, 2)
    gt = _points("gt_root", gt_root, 2)
    _same_shape(pred, gt)
    path = np.linalg.norm(np.diff(gt, axis=0), axis=-1).sum()
    if path <= 1e-9:
        raise ValueError("RTE is undefined for a ground-truth root that does not move (zero path length)")
    s, R, t = umeyama(pred, gt, with_scale=False)
    aligned = (R @ pred.T).T + t
    return np.linalg.norm(aligned - gt, axis=-1) / path * 100.0


def jitter(joints, fps: float) -> np.ndarray:
    """Jerk magnitude |x_{t+3} - 3 x_{t+2} + 3 x_{t+1} - x_t| fps^3 averaged over joints: m/s^3, n - 3 values.
    (EMDB/WHAM/GVHMR tables print it divided by 10, in units of 10 m/s^3.)"""
    x = _points("joints", joints, 3)
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if len(x) < 4:
        raise ValueError(f"jitter needs at least 4 frames, got {len(x)}")
    jerk = x[3:] - 3 * x[2:-1] + 3 * x[1:-2] - x[:-3]
    return np.linalg.norm(jerk, axis=-1).mean(axis=-1) * fps ** 3


def foot_sliding(pred_feet, gt_feet, contact_speed: float = FOOT_CONTACT_SPEED) -> np.ndarray:
    """Foot sliding: for every foot point (n, F, 3) and frame step where the ground-truth point moves less
    than `contact_speed` metres per frame (a contact), the predicted point's displacement over that step; mm,
    one value per contact (empty when the ground truth never plants a foot)."""
    pred = _points("pred_feet", pred_feet, 3)
    gt = _points("gt_feet", gt_feet, 3)
    _same_shape(pred, gt)
    contact = np.linalg.norm(np.diff(gt, axis=0), axis=-1) < contact_speed
    return np.linalg.norm(np.diff(pred, axis=0), axis=-1)[contact] * M_TO_MM


# Camera trajectory ------------------------------------------------------------------------------------------
def _poses(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (T, 4, 4) (world_from_cam), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf values")
    return arr


def align_trajectory(pred_world_from_cam, gt_world_from_cam, with_scale: bool = True) -> np.ndarray:
    """pred camera poses (T, 4, 4) mapped into the ground-truth world by the Sim(3) (or SE(3)) transform that
    best aligns the camera centres (Umeyama); the rotations are rotated and the translations scaled accordingly."""
    pred = _poses("pred_world_from_cam", pred_world_from_cam)
    gt = _poses("gt_world_from_cam", gt_world_from_cam)
    if pred.shape != gt.shape:
        raise ValueError(f"pred {pred.shape} and gt {gt.shape} camera trajectories must have the same length")
    s, R, t = umeyama(pred[:, :3, 3], gt[:, :3, 3], with_scale=with_scale)
    out = pred.copy()
    out[:, :3, :3] = R @ pred[:, :3, :3]
    out[:, :3, 3] = s * pred[:, :3, 3] @ R.T + t
    return out


def camera_ate(pred_world_from_cam, gt_world_from_cam, with_scale: bool = True) -> np.ndarray:
    """Absolute trajectory error: camera-centre distances after Sim(3) alignment, mm per frame (RMSE = the root
    of the mean square of these)."""
    aligned = align_trajectory(pred_world_from_cam, gt_world_from_cam, with_scale)
    gt = _poses("gt_world_from_cam", gt_world_from_cam)
    return np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=-1) * M_TO_MM


def camera_rpe(pred_world_from_cam, gt_world_from_cam, delta: int = 1, with_scale: bool = True):
    """Relative pose error over `delta` frames after Sim(3) alignment: the error E = (G_i^-1 G_{i+d})^-1
    (P_i^-1 P_{i+d}) of each relative motion; returns (translation mm (T - d), rotation degrees (T - d))."""
    P = align_trajectory(pred_world_from_cam, gt_world_from_cam, with_scale)
    G = _poses("gt_world_from_cam", gt_world_from_cam)
    if not 1 <= delta < len(G):
        raise ValueError(f"delta must be in [1, {len(G) - 1}] for {len(G)} poses, got {delta}")
    rel_p = np.linalg.inv(P[:-delta]) @ P[delta:]
    rel_g = np.linalg.inv(G[:-delta]) @ G[delta:]
    E = np.linalg.inv(rel_g) @ rel_p
    trans = np.linalg.norm(E[:, :3, 3], axis=-1) * M_TO_MM
    cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    return trans, np.degrees(np.arccos(cos))
