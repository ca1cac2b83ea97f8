"""Interpolation over time, one owner: values linearly (interpolate_linear) and rotations on SO(3), both by
scipy's Rotation: a time series by its Slerp (interpolate_rotations), two rotations a fraction of the way
(slerp, the same geodesic as Slerp's between two key rotations)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def interpolate_linear(times: np.ndarray, values: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation of values (K, ...) known at increasing times (K,) onto query (M,);
    constant beyond the ends."""
    values = np.asarray(values, dtype=np.float64)
    flat = values.reshape(len(times), -1)
    out = np.stack([np.interp(query, times, flat[:, d]) for d in range(flat.shape[1])], axis=1)
    return out.reshape((len(query),) + values.shape[1:])


def interpolate_rotations(times: np.ndarray, rotvecs: np.ndarray, query: np.ndarray) -> np.ndarray:
    """SO(3) slerp of axis-angle rotations (K, J, 3) known at increasing times (K,) onto query (M,) -> (M, J, 3);
    constant beyond the ends. Each step takes the shorter arc between consecutive known rotations."""
    rotvecs = np.asarray(rotvecs, dtype=np.float64)
    K, J = rotvecs.shape[:2]
    query = np.clip(np.asarray(query, dtype=np.float64), times[0], times[-1])
    if K == 1:
        return np.repeat(rotvecs, len(query), axis=0)
    out = np.empty((len(query), J, 3))
    for j in range(J):
        out[:, j] = Slerp(times, Rotation.from_rotvec(rotvecs[:, j]))(query).as_rotvec()
    return out


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Axis-angle rotations a -> b a fraction t of the way (shapes (..., 3), t broadcast over the leading axes);
    exactly b where t == 1 and a where t == 0."""
    t = np.broadcast_to(np.asarray(t, dtype=np.float64), a.shape[:-1])
    out = np.where(t[..., None] >= 1.0, b, a)
    mid = (t > 0) & (t < 1)
    if mid.any():
        ra, rb = Rotation.from_rotvec(a[mid]), Rotation.from_rotvec(b[mid])
        step = (ra.inv() * rb).as_rotvec() * t[mid][:, None]
        out[mid] = (ra * Rotation.from_rotvec(step)).as_rotvec()
    return out
