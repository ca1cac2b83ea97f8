"""Per-frame hand fits: finger articulation from MediaPipe's 21 hand landmarks (u, v, confidence), given the
body's wrist (world position and rotation) and the camera, smoothed over time.

The fingers move by anatomical degrees of freedom with joint limits (no learned hand prior: M3C has no open
hand pose data): each finger's first joint flexes and spreads, its second and third flex; the thumb's first
joint turns about three axes, its second flexes and spreads, its third flexes. Flexion turns a bone towards
the palm (axis bone x palm normal, from the rest hand), spread turns it about the palm normal. A joint's
axis-angle is the sum of its degrees of freedom along those axes, in the body's rest axes (SMPL-H's hand pose
convention).

The fit minimises, over the degrees of freedom and a small correction of the wrist's rotation,

    E = sum_i c_i |(p_i - p_0) - (o_i - o_0)|^2 / s^2 + |W_prior theta|^2 + w_wrist^2 |delta|^2
        + w_time^2 |theta - theta_prev|^2

with p_i the projected model landmarks, o_i the observed ones (0 = the wrist: the body's wrist need not
project exactly onto MediaPipe's), c_i their confidence and s the observed hand's size in pixels, so the
weights do not depend on how large the hand is in the image. The fitted poses are then smoothed over each run
of frames with a hand (smooth_dofs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from m3c.body.hands import HAND_PARENTS, MEDIAPIPE_FROM_HAND, SIDES, TIP_JOINTS, HandModel

# Degrees of freedom: (joint, axis, lower, upper) radians; axis 0 flexion, 1 spread, 2 twist (along the bone).
_FINGER = lambda f: [(3 * f, 0, -0.35, 1.6), (3 * f, 1, -0.35, 0.35), (3 * f + 1, 0, -0.2, 1.9),
                     (3 * f + 2, 0, -0.2, 1.4)]
DOFS = tuple(_FINGER(0) + _FINGER(1) + _FINGER(2) + _FINGER(3) + [
    (12, 0, -0.5, 1.0), (12, 1, -0.6, 0.6), (12, 2, -0.5, 0.5), (13, 0, -0.3, 1.0), (13, 1, -0.3, 0.3),
    (14, 0, -0.3, 1.4)])
NUM_DOFS = len(DOFS)
LOWER = np.array([d[2] for d in DOFS])
UPPER = np.array([d[3] for d in DOFS])
FLEXION = np.array([d[1] == 0 for d in DOFS])
MIN_CONFIDENCE = 0.3


@dataclass(frozen=True)
class FitWeights:
    prior: float = 0.05  # pull of every degree of freedom towards the rest hand
    wrist: float = 0.5  # per radian of wrist correction
    time: float = 0.3  # per radian of change from the previous frame's fit
    max_wrist_correction: float = 0.8  # radians


@dataclass
class HandFit:
    """One hand in one frame: dofs (NUM_DOFS,), hand_pose 15 x 3 axis-angle, wrist_correction (3,) axis-angle
    (the wrist's world rotation is R_wrist @ exp(wrist_correction)), rms_px (landmark residual)."""

    dofs: np.ndarray
    hand_pose: np.ndarray
    wrist_correction: np.ndarray
    rms_px: float


def hand_axes(hand: HandModel, betas) -> np.ndarray:
    """Per side and finger joint, the rest axes (2 x 15 x 3 x 3; rows: flexion, spread, twist): twist along
    the bone to the next joint (or tip), spread along the palm normal (the side of the palm, from the rest
    knuckles), flexion = bone x normal (a positive flexion turns the bone towards the palm)."""
    wrist, joints, tips = hand.rest(betas)
    axes = np.zeros((2, 15, 3, 3))
    for s in range(2):
        knuckles = joints[s][[0, 3, 6, 9]]
        along = knuckles.mean(axis=0) - wrist[s]
        across = knuckles[2] - knuckles[0]  # index -> pinky
        normal = np.cross(along, across) if s == 0 else np.cross(across, along)
        normal /= np.linalg.norm(normal)
        # The palm faces -y in the T-pose: orient the normal to the palm side.
        if normal[1] > 0:
            normal = -normal
        for j in range(15):
            child = [k for k, p in enumerate(HAND_PARENTS) if p == j]
            end = joints[s, child[0]] if child else tips[s, TIP_JOINTS.index(j)]
            bone = end - joints[s, j]
            bone /= np.linalg.norm(bone)
            n = normal - bone * (normal @ bone)
            n /= np.linalg.norm(n)
            axes[s, j] = [np.cross(bone, n), n, bone]
    return axes


def dofs_to_pose(dofs: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(..., NUM_DOFS) degrees of freedom -> (..., 15, 3) axis-angle, axes: 15 x 3 x 3 (one side's)."""
    pose = np.zeros(dofs.shape[:-1] + (15, 3))
    for d, (joint, axis, _, _) in enumerate(DOFS):
        pose[..., joint, :] += dofs[..., d, None] * axes[joint, axis]
    return pose


def _rodrigues(rotvec: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    k = rotvec / np.maximum(theta, 1e-12)
    x, y, z = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(rotvec.shape[:-1] + (3, 3))
    s, c = np.sin(theta)[..., None], np.cos(theta)[..., None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


class SideModel:
    """One hand of one shape, for batched landmark evaluation."""

    def __init__(self, hand: HandModel, betas, side: str):
        s = SIDES.index(side)
        wrist, joints, tips = hand.rest(betas)
        self.offsets = np.stack([joints[s, j] - (wrist[s] if p < 0 else joints[s, p])
                                 for j, p in enumerate(HAND_PARENTS)])
        self.tip_offsets = tips[s] - joints[s, list(TIP_JOINTS)]
        self.axes = hand_axes(hand, betas)[s]

    def landmarks(self, dofs: np.ndarray, wrist_rotation: np.ndarray,
                  wrist_position: np.ndarray) -> np.ndarray:
        """(K, NUM_DOFS), (K, 3, 3), (3,) -> (K, 21, 3) world landmarks in MediaPipe order."""
        R_local = _rodrigues(dofs_to_pose(dofs, self.axes))  # K x 15 x 3 x 3
        K = len(dofs)
        R_world = np.zeros((K, 15, 3, 3))
        points = np.zeros((K, 21, 3))  # wrist, 15 joints, 5 tips
        points[:, 0] = wrist_position
        for j, p in enumerate(HAND_PARENTS):
            parent_R = wrist_rotation if p < 0 else R_world[:, p]
            points[:, 1 + j] = points[:, 0 if p < 0 else 1 + p] + parent_R @ self.offsets[j]
            R_world[:, j] = parent_R @ R_local[:, j]
        for f, j in enumerate(TIP_JOINTS):
            points[:, 16 + f] = points[:, 1 + j] + R_world[:, j] @ self.tip_offsets[f]
        return points[:, list(MEDIAPIPE_FROM_HAND)]


def fit_hand(side_model: SideModel, observed: np.ndarray, wrist_rotation: np.ndarray,
             wrist_position: np.ndarray, world_from_cam: np.ndarray, intrinsics,
             previous: HandFit | None = None, weights: FitWeights = FitWeights(),
             max_evaluations: int = 40) -> HandFit | None:
    """The fit of one hand in one frame (module docstring). observed: 21 x 3 landmarks (u, v, confidence);
    wrist_rotation 3 x 3 and wrist_position (3,) in the world; world_from_cam 4 x 4; intrinsics fx, fy, cx,
    cy. None when the observation is unusable (the wrist or too few landmarks below MIN_CONFIDENCE)."""
    observed = np.asarray(observed, dtype=np.float64)
    conf = np.where(np.isfinite(observed[:, 2]), observed[:, 2], 0.0)
    if conf[0] < MIN_CONFIDENCE or (conf >= MIN_CONFIDENCE).sum() < 8:
        return None
    w = np.sqrt(np.where(conf[1:] >= MIN_CONFIDENCE, conf[1:], 0.0))[:, None]
    rel_obs = observed[1:, :2] - observed[0, :2]
    scale = max(float(np.linalg.norm(observed[9, :2] - observed[0, :2])), 1.0)  # wrist -> middle knuckle
    R_cam = np.asarray(world_from_cam)[:3, :3]
    c_cam = np.asarray(world_from_cam)[:3, 3]
    k = np.asarray(intrinsics, dtype=np.float64)
    prior_weights = np.full(NUM_DOFS, weights.prior)
    prev = previous.dofs if previous is not None else None

    def residuals(x: np.ndarray) -> np.ndarray:
        """x: (K, NUM_DOFS + 3) -> (K, R)."""
        dofs, delta = x[:, :NUM_DOFS], x[:, NUM_DOFS:]
        R = wrist_rotation @ _rodrigues(delta)
        cam = (side_model.landmarks(dofs, R, wrist_position) - c_cam) @ R_cam
        z = np.maximum(cam[..., 2], 1e-3)
        pix = np.stack([k[0] * cam[..., 0] / z + k[2], k[1] * cam[..., 1] / z + k[3]], axis=-1)
        rel = pix[:, 1:] - pix[:, :1]
        parts = [(w * (rel - rel_obs) / scale).reshape(len(x), -1), prior_weights * dofs,
                 weights.wrist * delta]
        if prev is not None:
            parts.append(weights.time * (dofs - prev))
        return np.concatenate(parts, axis=1)

    def fun(x):
        return residuals(x[None])[0]

    def jac(x):
        eps = 1e-6
        batch = x[None] + eps * np.eye(len(x))
        return ((residuals(batch) - residuals(x[None])) / eps).T

    lower = np.r_[LOWER, -np.full(3, weights.max_wrist_correction)]
    upper = np.r_[UPPER, np.full(3, weights.max_wrist_correction)]
    # Starts: the previous frame's fit, else the rest hand and a half-closed one (the 2D fit has local
    # minima).
    starts = [np.r_[previous.dofs, previous.wrist_correction]] if previous is not None else [
        np.zeros(NUM_DOFS + 3), np.r_[np.where(FLEXION, 0.6, 0.0), np.zeros(3)]]
    best = None
    for start in starts:
        start = np.clip(start, lower + 1e-9, upper - 1e-9)
        solution = least_squares(fun, start, jac=jac, bounds=(lower, upper), method="trf",
                                 max_nfev=max_evaluations)
        if best is None or solution.cost < best.cost:
            best = solution
    solution = best
    x = solution.x
    dofs, delta = x[:NUM_DOFS], x[NUM_DOFS:]
    r = solution.fun[:40].reshape(20, 2) * scale
    used = w[:, 0] > 0
    rms = float(np.sqrt(np.mean(np.sum(r[used] ** 2, axis=1) / np.maximum(w[used, 0] ** 2, 1e-12))))
    return HandFit(dofs, dofs_to_pose(dofs, side_model.axes), delta, rms)


def smooth_dofs(values: np.ndarray, found: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """Gaussian smoothing over time (sigma in frames) of per-frame values (T x D) within each run of
    consecutive found frames; frames without a fit stay NaN."""
    out = np.full(values.shape, np.nan)
    T = len(values)
    radius = int(np.ceil(3 * sigma))
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    for t in np.flatnonzero(found):
        idx = t + offsets
        ok = (idx >= 0) & (idx < T)
        idx, kern = idx[ok], kernel[ok]
        use = found[idx]
        # Stay within the run: stop at the first gap either side.
        left = np.flatnonzero(~use & (idx < t))
        right = np.flatnonzero(~use & (idx > t))
        keep = np.ones(len(idx), bool)
        if len(left):
            keep[: left[-1] + 1] = False
        if len(right):
            keep[right[0]:] = False
        out[t] = np.sum(kern[keep, None] * values[idx[keep]], axis=0) / kern[keep].sum()
    return out
