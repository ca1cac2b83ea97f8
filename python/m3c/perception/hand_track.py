"""The hands over a track's whole time: one least-squares problem per hand and run of frames, over every
frame's finger degrees of freedom (m3c.perception.hand_fit.DOFS) and wrist-rotation correction at once, with
the body fixed (its wrists are the world optimization's).

Unknowns x_t = (theta_t, delta_t) for each frame t of a run (theta: NUM_DOFS finger degrees of freedom within
the joint limits, which are bounds of the solve; delta: the wrist's correction, world rotation
R_wrist,t exp(delta_t), bounded by max_wrist_correction). The energy

    E = sum_t sum_i c_ti |(p_ti - p_t0) - (o_ti - o_t0)|^2 / s_t^2             reprojection (observed frames)
        + sum_t |w_prior theta_t|^2 + |w_wrist delta_t|^2                       pull to the rest hand
        + sum_t |w_velocity (x_t+1 - x_t)|^2 + |w_accel (x_t+1 - 2 x_t + x_t-1)|^2   smoothness

with p_ti the model's landmark i projected through the world camera of frame t (world_from_cam_t, K),
o_ti MediaPipe's, c_ti its confidence, s_t the observed hand's size (wrist to middle knuckle, pixels) and
i = 0 the wrist, as m3c.perception.hand_fit's per-frame fit. Frames without an observation inside a run (gaps
of at most max_gap frames) are held by the smoothness and prior terms alone: they are interpolated.

The Jacobian is analytic: a degree of freedom d of finger joint j turns joint j's world frame by
w_d = R_world,j J_r(phi_j) a_d (phi_j the joint's axis-angle, a_d the dof's axis, J_r SO(3)'s right Jacobian),
so every landmark below j moves by w_d x (p - x_j); a wrist correction's component k turns every landmark
about the wrist by R_w J_r(delta) e_k; the pinhole's derivative maps those onto pixels. It is checked against
finite differences in tests/python/test_hand_track.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from m3c.body.hands import HAND_PARENTS, MEDIAPIPE_FROM_HAND, TIP_JOINTS
from m3c.perception.hand_fit import (DOFS, LOWER, MIN_CONFIDENCE, NUM_DOFS, UPPER, SideModel, _rodrigues,
                                     dofs_to_pose)

NUM_VARS = NUM_DOFS + 3


@dataclass(frozen=True)
class TrackWeights:
    prior: float = 0.05           # per radian of every degree of freedom (as the per-frame fit)
    wrist: float = 0.5            # per radian of wrist correction (as the per-frame fit)
    velocity: float = 0.3         # per radian of change between consecutive frames
    accel: float = 50.0           # per radian of second difference over three frames
    max_wrist_correction: float = 0.8   # radians
    max_gap: int = 5              # frames without a hand bridged inside a run
    max_evaluations: int = 30


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    return np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(v.shape[:-1] + (3, 3))


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) SO(3)'s right Jacobian: exp(phi + e) = exp(phi) exp(J_r(phi) e), first
    order."""
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = _skew(phi)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t ** 3)
    return np.eye(3) - a * K + b * (K @ K)


def _descendants() -> np.ndarray:
    """(16, 21) bool: row j < 15 the landmarks (MediaPipe rows) that move with finger joint j; row 15 those
    that move with the wrist (all but the wrist itself)."""
    below = np.zeros((16, 21), bool)
    source_of_row = list(MEDIAPIPE_FROM_HAND)   # 0 wrist, 1 + j joint j, 16 + f tip f
    for row, src in enumerate(source_of_row):
        if src == 0:
            continue
        below[15, row] = True
        k = src - 1 if src <= 15 else TIP_JOINTS[src - 16]
        while k >= 0:
            below[k, row] = True
            k = HAND_PARENTS[k]
    return below


_BELOW = _descendants()
_ROW_OF_JOINT = [list(MEDIAPIPE_FROM_HAND).index(1 + j) for j in range(15)]


class HandProjector:
    """The landmarks of one hand of one shape seen by per-frame cameras, with their Jacobian."""

    def __init__(self, side: SideModel, wrist_rotation: np.ndarray, wrist_position: np.ndarray,
                 world_from_cam: np.ndarray, intrinsics: np.ndarray):
        """wrist_rotation (T, 3, 3), wrist_position (T, 3) the body's world wrists; world_from_cam (T, 4, 4);
        intrinsics (T, 4) or (4,) fx, fy, cx, cy."""
        self.side = side
        self.R_wrist = np.asarray(wrist_rotation, dtype=np.float64)
        self.x_wrist = np.asarray(wrist_position, dtype=np.float64)
        w = np.asarray(world_from_cam, dtype=np.float64)
        self.R_cam, self.c_cam = w[:, :3, :3], w[:, :3, 3]
        k = np.asarray(intrinsics, dtype=np.float64)
        self.K = np.broadcast_to(k, (len(w), 4)) if k.ndim == 1 else k

    def pixels(self, x: np.ndarray, jacobian: bool = False):
        """x (T, NUM_VARS) -> pixels (T, 21, 2) of the 21 landmarks (MediaPipe order) and, with jacobian,
        d pixels / d x (T, 21, 2, NUM_VARS)."""
        theta, delta = x[:, :NUM_DOFS], x[:, NUM_DOFS:]
        R_w = self.R_wrist @ _rodrigues(delta)
        # Forward kinematics as SideModel.landmarks, keeping the joints' world frames.
        phi = dofs_to_pose(theta, self.side.axes)          # T x 15 x 3
        R_local = _rodrigues(phi)
        T = len(x)
        R_world = np.zeros((T, 15, 3, 3))
        src = np.zeros((T, 21, 3))                          # wrist, 15 joints, 5 tips
        src[:, 0] = self.x_wrist
        for j, p in enumerate(HAND_PARENTS):
            parent_R = R_w if p < 0 else R_world[:, p]
            src[:, 1 + j] = src[:, 0 if p < 0 else 1 + p] + parent_R @ self.side.offsets[j]
            R_world[:, j] = parent_R @ R_local[:, j]
        for f, j in enumerate(TIP_JOINTS):
            src[:, 16 + f] = src[:, 1 + j] + R_world[:, j] @ self.side.tip_offsets[f]
        world = src[:, list(MEDIAPIPE_FROM_HAND)]          # T x 21 x 3
        cam = np.einsum("tji,tkj->tki", self.R_cam, world - self.c_cam[:, None])
        z = np.maximum(cam[..., 2], 1e-3)
        fx, fy, cx, cy = (self.K[:, i, None] for i in range(4))
        pix = np.stack([fx * cam[..., 0] / z + cx, fy * cam[..., 1] / z + cy], axis=-1)
        if not jacobian:
            return pix
        # World angular velocity of each variable and the pivot it turns its landmarks about.
        omega = np.zeros((T, NUM_VARS, 3))
        pivot = np.zeros((T, NUM_VARS, 3))
        moves = np.zeros((NUM_VARS, 21), bool)
        Jr = right_jacobian(phi)                            # T x 15 x 3 x 3
        for d, (joint, axis, _, _) in enumerate(DOFS):
            omega[:, d] = np.einsum("tab,tbc,c->ta", R_world[:, joint], Jr[:, joint],
                                    self.side.axes[joint, axis])
            pivot[:, d] = world[:, _ROW_OF_JOINT[joint]]
            moves[d] = _BELOW[joint]
        Jd = R_w @ right_jacobian(delta)                    # T x 3 x 3: columns the axes of delta's parts
        for k in range(3):
            omega[:, NUM_DOFS + k] = Jd[:, :, k]
            pivot[:, NUM_DOFS + k] = self.x_wrist
            moves[NUM_DOFS + k] = _BELOW[15]
        d_world = np.cross(omega[:, :, None], world[:, None] - pivot[:, :, None]) * moves[None, :, :, None]
        d_cam = np.einsum("tji,tvkj->tvki", self.R_cam, d_world)          # T x V x 21 x 3
        zz = z[:, None]
        du = fx[:, None] * (d_cam[..., 0] / zz - cam[:, None, :, 0] * d_cam[..., 2] / zz ** 2)
        dv = fy[:, None] * (d_cam[..., 1] / zz - cam[:, None, :, 1] * d_cam[..., 2] / zz ** 2)
        return pix, np.stack([du, dv], axis=-1).transpose(0, 2, 3, 1)   # T x 21 x 2 x V


def _runs(found: np.ndarray, max_gap: int) -> list[tuple[int, int]]:
    """[first, stop) spans from the first to the last found frame of each group of found frames whose gaps
    are at most max_gap frames."""
    idx = np.flatnonzero(found)
    if not len(idx):
        return []
    runs, start = [], idx[0]
    for a, b in zip(idx[:-1], idx[1:]):
        if b - a - 1 > max_gap:
            runs.append((int(start), int(a) + 1))
            start = b
    runs.append((int(start), int(idx[-1]) + 1))
    return runs


def fit_hand_run(projector: HandProjector, observed: np.ndarray, start: np.ndarray,
                 weights: TrackWeights = TrackWeights()) -> np.ndarray:
    """One run's solve (module docstring). observed (T, 21, 3) u, v, confidence (NaN rows: no observation
    that frame); start (T, NUM_VARS) the first guess (finite). Returns x (T, NUM_VARS)."""
    T = len(observed)
    observed = np.asarray(observed, dtype=np.float64)
    conf = np.where(np.isfinite(observed[..., 2]), observed[..., 2], 0.0)
    usable = (conf[:, 0] >= MIN_CONFIDENCE) & ((conf >= MIN_CONFIDENCE).sum(axis=1) >= 8)
    w = np.sqrt(np.where(conf[:, 1:] >= MIN_CONFIDENCE, conf[:, 1:], 0.0)) * usable[:, None]   # T x 20
    obs = np.nan_to_num(observed[..., :2])
    rel_obs = obs[:, 1:] - obs[:, :1]
    scale = np.maximum(np.linalg.norm(obs[:, 9] - obs[:, 0], axis=-1), 1.0)
    coef = w / scale[:, None]                                            # T x 20
    # The linear terms: prior, wrist, velocity and acceleration, a constant sparse matrix A (x flattened).
    n = T * NUM_VARS
    diag = np.tile(np.r_[np.full(NUM_DOFS, weights.prior), np.full(3, weights.wrist)], T)
    blocks = [sparse.diags(diag)]
    if T > 1:
        D1 = sparse.diags([-1.0, 1.0], [0, NUM_VARS], shape=(n - NUM_VARS, n))
        blocks.append(weights.velocity * D1)
    if T > 2:
        D2 = sparse.diags([1.0, -2.0, 1.0], [0, NUM_VARS, 2 * NUM_VARS], shape=(n - 2 * NUM_VARS, n))
        blocks.append(weights.accel * D2)
    A = sparse.vstack(blocks, format="csr")
    rows = np.arange(T * 40).reshape(T, 20, 2)
    cols = np.arange(n).reshape(T, NUM_VARS)
    jr = np.broadcast_to(rows[..., None], (T, 20, 2, NUM_VARS)).ravel()
    jc = np.broadcast_to(cols[:, None, None, :], (T, 20, 2, NUM_VARS)).ravel()

    def fun(flat):
        x = flat.reshape(T, NUM_VARS)
        pix = projector.pixels(x)
        rel = pix[:, 1:] - pix[:, :1]
        return np.concatenate([(coef[..., None] * (rel - rel_obs)).ravel(), A @ flat])

    def jac(flat):
        x = flat.reshape(T, NUM_VARS)
        _, J = projector.pixels(x, jacobian=True)          # T x 21 x 2 x V
        J_rel = (J[:, 1:] - J[:, :1]) * coef[..., None, None]
        reproj = sparse.csr_matrix((J_rel.ravel(), (jr, jc)), shape=(T * 40, n))
        return sparse.vstack([reproj, A], format="csr")

    lower = np.tile(np.r_[LOWER, -np.full(3, weights.max_wrist_correction)], T)
    upper = np.tile(np.r_[UPPER, np.full(3, weights.max_wrist_correction)], T)
    x0 = np.clip(np.asarray(start, dtype=np.float64).ravel(), lower + 1e-9, upper - 1e-9)
    solution = least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf", tr_solver="lsmr",
                             max_nfev=weights.max_evaluations, x_scale=1.0)
    return solution.x.reshape(T, NUM_VARS)


def fit_hand_track(side: SideModel, observed: np.ndarray, wrist_rotation: np.ndarray,
                   wrist_position: np.ndarray, world_from_cam: np.ndarray, intrinsics: np.ndarray,
                   start: np.ndarray, weights: TrackWeights = TrackWeights()) -> np.ndarray:
    """One hand over a track: observed (T, 21, 3) (NaN: no hand that frame), the body's world wrists
    (T, 3, 3), (T, 3), the cameras world_from_cam (T, 4, 4) and intrinsics ((T, 4) or (4,)), start (T,
    NUM_VARS) the per-frame fits (NaN where none). Returns (T, NUM_VARS): each run of frames with a hand (gaps
    of at most max_gap frames bridged) solved jointly; NaN outside those runs."""
    observed = np.asarray(observed, dtype=np.float64)
    start = np.asarray(start, dtype=np.float64)
    T = len(observed)
    for name, a, shape in (("wrist_rotation", wrist_rotation, (T, 3, 3)), ("wrist_position", wrist_position,
                           (T, 3)), ("world_from_cam", world_from_cam, (T, 4, 4)), ("start", start,
                           (T, NUM_VARS)), ("observed", observed, (T, 21, 3))):
        if np.shape(a) != shape:
            raise ValueError(f"fit_hand_track: {name} has shape {np.shape(a)}, expected {shape}")
    found = np.isfinite(start).all(axis=1) & np.isfinite(observed[:, 0, :2]).all(axis=1)
    out = np.full((T, NUM_VARS), np.nan)
    k = np.asarray(intrinsics, dtype=np.float64)
    for a, b in _runs(found, weights.max_gap):
        span = np.arange(a, b)
        guess = start[span].copy()
        ok = found[span]
        for v in range(NUM_VARS):   # gap frames start on the line between their neighbours' fits
            guess[:, v] = np.interp(span, span[ok], guess[ok, v])
        obs = observed[span].copy()
        obs[~ok] = np.nan
        projector = HandProjector(side, wrist_rotation[span], wrist_position[span], world_from_cam[span],
                                  k if k.ndim == 1 else k[span])
        out[span] = fit_hand_run(projector, obs, guess, weights)
    return out
