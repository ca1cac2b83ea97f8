"""Trajectory evaluation: Sim(3) alignment (Umeyama) and absolute trajectory error."""

from __future__ import annotations

import numpy as np


def umeyama_sim3(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity with target ~= scale * rotation @ source + translation.

    source, target: (N, 3) points, N >= 3 and not all collinear for a unique rotation.
    Returns (scale, rotation (3, 3), translation (3,)).
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or source.shape[0] < 3:
        raise ValueError(
            f"source and target must both have shape (N >= 3, 3), got {source.shape} and {target.shape}")
    mu_s, mu_t = source.mean(0), target.mean(0)
    xs, xt = source - mu_s, target - mu_t
    cov = xt.T @ xs / len(source)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    var_s = (xs ** 2).sum() / len(source)
    if var_s <= 0:
        raise ValueError("source points are all identical; a similarity cannot be fitted")
    scale = float(np.trace(np.diag(d) @ sign) / var_s)
    translation = mu_t - scale * rotation @ mu_s
    return scale, rotation, translation


def path_length(positions: np.ndarray) -> float:
    """Sum of the distances between consecutive positions (N, 3)."""
    positions = np.asarray(positions, dtype=np.float64)
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())


def absolute_trajectory_error(estimated_world_from_cam: np.ndarray, true_world_from_cam: np.ndarray) -> float:
    """RMS camera-centre error after Sim(3) alignment of the estimate onto the truth (units of the truth)."""
    est = np.asarray(estimated_world_from_cam)[:, :3, 3]
    gt = np.asarray(true_world_from_cam)[:, :3, 3]
    scale, rotation, translation = umeyama_sim3(est, gt)
    aligned = scale * est @ rotation.T + translation
    return float(np.sqrt(np.mean(np.sum((aligned - gt) ** 2, axis=1))))


def relative_ate(estimated_world_from_cam: np.ndarray, true_world_from_cam: np.ndarray) -> float:
    """ATE (Sim(3)-aligned) as a fraction of the true path length."""
    return absolute_trajectory_error(estimated_world_from_cam, true_world_from_cam) / path_length(
        np.asarray(true_world_from_cam)[:, :3, 3])
