"""Plausibility of a world-frame motion where there is no ground truth: figures a person can check against what
people do (a walker moves at 1-1.5 m/s, a planted foot stands still, nobody walks through the floor).

Per track, from its world joints (SMPL 24, metres), the frame rate and its ground plane (n . x + d = 0, the normal
pointing up; y = 0 when none is given):
  mean_speed_mps, peak_speed_mps   horizontal pelvis speed after a 0.5 s smoothing (the gait's sway out)
  path_length_m, displacement_m    the smoothed pelvis path and the straight line from its start to its end
  path_ratio                       path length / displacement (1 for a straight walk; large for a wandering pelvis)
  slow_foot_speed_mps              median over frames of the slower foot's speed (a foot: the slower of its ankle
                                   and foot joints). Retargeted CMU motion capture walking at 1.3 m/s scores 0.13,
                                   standing and jumping 0.07: joint noise and the roll from heel to toe
                                   keep it above zero; sliding feet score several tenths
  below_ground_fraction            share of frames whose lowest foot joint is more than 2 cm below the ground
  penetration_m                    the deepest any foot joint goes below the ground (0 if never)
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

PELVIS = (1, 2)              # the hips
FEET = ((7, 10), (8, 11))    # (ankle, foot) joints of the left and right foot
SMOOTHING_S = 0.5
BELOW_GROUND_TOLERANCE = 0.02
# Heights are measured to the joints, not the soles: a planted ankle joint sits about 7 cm and a foot joint about
# 2.5 cm above the ground (the open body model at rest: 0.069-0.076 and 0.023-0.030 m over betas -2..2).
FOOT_JOINT_HEIGHT = {7: 0.07, 8: 0.07, 10: 0.025, 11: 0.025}


def _heights(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Signed distance above the plane of points (n, K, 3) with per-frame planes normal (n, 3), offset (n,)."""
    unit = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    scale = np.linalg.norm(normal, axis=-1)
    return np.einsum("nkd,nd->nk", points, unit) + (offset / scale)[:, None]


def track_plausibility(joints: np.ndarray, fps: float, ground_normal=None, ground_offset=None) -> dict:
    """Figures of one track: joints (n, 24, 3) world over consecutive frames; ground planes (n, 3) and (n,) or
    None for y = 0."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1] < 12 or joints.shape[2] != 3:
        raise ValueError(f"joints must have shape (n, 24, 3), got {joints.shape}")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    n = len(joints)
    if n < 2 or not np.all(np.isfinite(joints)):
        raise ValueError("plausibility needs at least 2 frames of finite joints")
    if ground_normal is None:
        ground_normal, ground_offset = np.tile([0.0, 1.0, 0.0], (n, 1)), np.zeros(n)
    normal = np.asarray(ground_normal, dtype=np.float64).reshape(n, 3)
    offset = np.asarray(ground_offset, dtype=np.float64).reshape(n)
    # Horizontal motion: components along the ground.
    unit = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    # A quadratic Savitzky-Golay smoothing over 0.5 s: removes the gait's sway, keeps steady motion exact up to
    # the ends (a moving average would slow the first and last quarter second).
    pelvis = joints[:, list(PELVIS)].mean(axis=1)
    window = min(n, round(SMOOTHING_S * fps)) // 2 * 2 + 1
    if window > n:
        window -= 2
    if window >= 3:
        pelvis = savgol_filter(pelvis, window, polyorder=min(2, window - 1), axis=0, mode="interp")
    step = np.diff(pelvis, axis=0)
    step -= (step * unit[1:]).sum(-1, keepdims=True) * unit[1:]
    speed = np.linalg.norm(step, axis=-1) * fps
    path = float(np.linalg.norm(step, axis=-1).sum())
    line = pelvis[-1] - pelvis[0]
    line -= (line @ unit[-1]) * unit[-1]
    displacement = float(np.linalg.norm(line))
    # A planted foot has its heel (ankle joint) or its toes (foot joint) still: each foot moves at the slower of
    # its two joints, and the slower foot is the one that may be planted.
    joint_speed = np.linalg.norm(np.diff(joints, axis=0), axis=-1) * fps  # (n - 1, 24)
    slow_foot = np.min([joint_speed[:, list(pair)].min(axis=1) for pair in FEET], axis=0)
    ids = [j for pair in FEET for j in pair]
    heights = _heights(joints[:, ids], normal, offset) - np.array([FOOT_JOINT_HEIGHT[j] for j in ids])
    lowest = heights.min(axis=1)
    return {
        "frames": int(n),
        "mean_speed_mps": float(speed.mean()),
        "peak_speed_mps": float(speed.max()),
        "path_length_m": path,
        "displacement_m": displacement,
        "path_ratio": float(path / displacement) if displacement > 1e-3 else None,
        "slow_foot_speed_mps": float(np.median(slow_foot)),
        "below_ground_fraction": float((lowest < -BELOW_GROUND_TOLERANCE).mean()),
        "penetration_m": float(max(0.0, -lowest.min())),
    }


def results_plausibility(arrays: dict) -> list[dict | None]:
    """Per track of a results.npz dict: the figures over its longest run of consecutive valid frames (None for a
    track shorter than 2 frames), with the track's per-frame ground planes where it has them."""
    fps = float(arrays["fps"])
    out = []
    for p in range(len(arrays["track_ids"])):
        valid = np.asarray(arrays["valid"][p], bool) & np.isfinite(arrays["world_joints"][p]).all(axis=(1, 2))
        frames = np.flatnonzero(valid)
        if len(frames) < 2:
            out.append(None)
            continue
        breaks = np.flatnonzero(np.diff(frames) != 1) + 1
        runs = np.split(frames, breaks)
        run = max(runs, key=len)
        if len(run) < 2:
            out.append(None)
            continue
        normal, offset = arrays["ground_normal"][p, run], arrays["ground_offset"][p, run]
        planes = np.isfinite(normal).all() and np.isfinite(offset).all()
        out.append(track_plausibility(arrays["world_joints"][p, run], fps, normal if planes else None,
                                      offset if planes else None))
    return out
