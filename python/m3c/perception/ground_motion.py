"""How fast each foot moves against the ground under it, read from the images: a cue for contacts that works in a
moving camera and does not need the person's depth to be right.

A planted foot moves in the image exactly as the ground around it does, whatever the camera does; a swinging
foot does not. Per frame, the ground's image motion near each foot point is the median optical flow (pyramidal
Lucas-Kanade, kept only where tracking forward and back returns to the start) of points on rings around it that no
person covers; the foot point's own image velocity comes from its keypoint track. Their difference, in pixels per
second, becomes metres per second at the foot's depth (depth / focal length): an error in the depth scales the
speed but cannot make a still foot move, so the cue stays sharp under a monocular fit's depth jitter.

Blind spot: motion along the viewing ray does not show in the image (a foot swinging straight at the camera);
the contacts' height factor covers it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from m3c.perception.contacts import local_velocities
from m3c.perception.types import NUM_COCO, NUM_WITH_FEET

# Image points that stand for CONTACT_JOINTS (left/right ankle, left/right foot): the heels and big toes of the
# foot keypoints, the COCO ankles where those are missing.
HEELS, TOES, ANKLES = (NUM_COCO, NUM_COCO + 1), (NUM_COCO + 2, NUM_COCO + 3), (15, 16)


@dataclass
class GroundMotionConfig:
    """rings: radii of the sample rings around a foot point, in units of the person's box height; points: samples
    per ring; min_points: fewer surviving samples give no estimate (NaN); max_round_trip: pixels a sample may miss
    its start by when tracked forward then back; window: Lucas-Kanade window (pixels) and levels: its pyramid;
    min_confidence: keypoints below it are missing; speed_window_seconds: half-width of the line fits of the foot
    points' image velocities; max_foreshortening: see ground_speeds."""

    enabled: bool = False  # opt-in: see README, "Contacts from the images"
    rings: tuple = (0.06, 0.1, 0.15)
    points: int = 16
    min_points: int = 6
    max_round_trip: float = 1.0
    window: int = 21
    levels: int = 3
    min_confidence: float = 0.3
    speed_window_seconds: float = 0.05
    max_foreshortening: float = 4.0

    def __post_init__(self):
        self.rings = tuple(float(r) for r in self.rings)
        if not self.rings or min(self.rings) <= 0 or self.points < 1 or self.min_points < 1:
            raise ValueError("ground_motion: rings must be positive, points and min_points >= 1")
        if (self.window < 3 or self.levels < 0 or self.max_round_trip <= 0 or self.speed_window_seconds <= 0
                or self.max_foreshortening < 1):
            raise ValueError("ground_motion: window >= 3, levels >= 0, max_round_trip and speed_window_seconds > 0, "
                             "max_foreshortening >= 1")


def contact_pixels(keypoints: np.ndarray, min_confidence: float) -> np.ndarray:
    """(n, 4, 2) image points of CONTACT_JOINTS from keypoints (n, K, 3) (K = 17 or 21): heels for the ankles and
    big toes for the feet where seen, else the ankles; NaN where none is."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if keypoints.ndim != 3 or keypoints.shape[1:] not in ((NUM_COCO, 3), (NUM_WITH_FEET, 3)):
        raise ValueError(f"keypoints must have shape (n, 17 or 21, 3), got {keypoints.shape}")
    out = np.full((len(keypoints), 4, 2), np.nan)
    feet = keypoints.shape[1] == NUM_WITH_FEET
    for slot, (ankle, foot) in enumerate(zip(ANKLES + ANKLES, (HEELS + TOES) if feet else (None,) * 4)):
        for row in (ankle, foot):  # the foot point, where seen, wins
            if row is None:
                continue
            seen = keypoints[:, row, 2] >= min_confidence
            out[seen, slot] = keypoints[seen, row, :2]
    return out


def ring_samples(points: np.ndarray, heights: np.ndarray, config: GroundMotionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Sample points (S, 2) on rings around points (P, 2) with radii config.rings x heights (P,), and the index
    (S,) of the point each belongs to."""
    angles = np.linspace(0.0, 2.0 * np.pi, config.points, endpoint=False)
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (A, 2)
    radii = np.asarray(config.rings)[None, :, None, None] * np.asarray(heights, dtype=np.float64)[:, None, None, None]
    samples = points[:, None, None, :] + radii * unit[None, None]  # (P, R, A, 2)
    owner = np.broadcast_to(np.arange(len(points))[:, None, None], samples.shape[:3])
    return samples.reshape(-1, 2), owner.reshape(-1)


def ground_flow(previous: np.ndarray, current: np.ndarray, points: np.ndarray, heights: np.ndarray,
                people: np.ndarray | None, config: GroundMotionConfig) -> np.ndarray:
    """Image motion (P, 2) in pixels from gray frame `previous` to `current` (H, W) uint8 of the ground around
    points (P, 2) of `previous` (NaN rows are skipped) of people whose boxes are heights (P,) pixels tall; people:
    (H, W) bool, True where any person is in `previous` (those pixels are not ground). NaN where under
    config.min_points samples survive."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    out = np.full(points.shape, np.nan)
    live = np.isfinite(points).all(axis=1) & (np.asarray(heights) > 0)
    if not live.any():
        return out
    samples, owner = ring_samples(points[live], np.asarray(heights, dtype=np.float64)[live], config)
    h, w = previous.shape[:2]
    col, row = np.round(samples[:, 0]).astype(int), np.round(samples[:, 1]).astype(int)
    keep = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    if people is not None:
        keep[keep] &= ~people[row[keep], col[keep]]
    samples, owner = samples[keep].astype(np.float32), owner[keep]
    if len(samples) == 0:
        return out
    lk = dict(winSize=(config.window, config.window), maxLevel=config.levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    forward, ok, _ = cv2.calcOpticalFlowPyrLK(previous, current, samples.reshape(-1, 1, 2), None, **lk)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(current, previous, forward, None, **lk)
    forward, back = forward.reshape(-1, 2), back.reshape(-1, 2)
    round_trip = np.linalg.norm(back - samples, axis=1)
    good = (ok.ravel() == 1) & (ok_back.ravel() == 1) & (round_trip <= config.max_round_trip)
    flow = forward - samples
    index = np.flatnonzero(live)
    for p in range(len(index)):
        mine = good & (owner == p)
        if mine.sum() >= config.min_points:
            out[index[p]] = np.median(flow[mine], axis=0)
    return out


def ground_speeds(pixels: np.ndarray, flow_next: np.ndarray, frame_ids: np.ndarray, fps: float, points: np.ndarray,
                  focal: float, config: GroundMotionConfig, up: np.ndarray | None = None) -> np.ndarray:
    """Speeds (n, P) in m/s of image points pixels (n, P, 2) against the ground under them, for a track seen in
    frames frame_ids (n,) at fps; flow_next (n, P, 2): the ground's image motion near each point from its frame
    to the next (NaN where unknown); points (n, P, 3): the points in the camera (metres); focal pixels. The
    ground's velocity at a frame is the mean of its motion from the frame before and to the frame after; NaN where
    the point or the ground's motion is unknown.

    up None: the relative image speed at the point's depth (depth / focal), as if it moved across the view. up
    (3,), the ground's normal in the camera: the relative image velocity taken back onto the ground plane through
    the point, which undoes the foreshortening of motion along the viewing ray (a foot swinging away from a camera
    behind the walker), by at most config.max_foreshortening (a grazing view would amplify keypoint jitter
    without bound)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    n, P = pixels.shape[:2]
    frame_ids = np.asarray(frame_ids)
    if flow_next.shape != pixels.shape or points.shape != (n, P, 3) or frame_ids.shape != (n,):
        raise ValueError(f"flow_next must be {pixels.shape}, points ({n}, {P}, 3) and frame_ids ({n},)")
    # The ground's motion into each frame: the flow stored at the frame before, when the track was seen there.
    flow_prev = np.full(pixels.shape, np.nan)
    follows = np.flatnonzero(np.diff(frame_ids) == 1)
    flow_prev[follows + 1] = flow_next[follows]
    both = np.stack([flow_prev, flow_next])
    counted = np.isfinite(both).all(axis=-1)
    ground = np.where(counted.any(axis=0)[..., None],
                      np.nansum(np.where(counted[..., None], both, 0.0), axis=0) /
                      np.maximum(counted.sum(axis=0), 1)[..., None], np.nan) * fps  # px/s
    times = frame_ids / fps
    velocity = np.full(pixels.shape, np.nan)
    for p in range(P):
        seen = np.isfinite(pixels[:, p]).all(axis=1)
        if seen.sum() >= 2:
            velocity[seen, p] = local_velocities(pixels[seen, p][:, None], times[seen],
                                                 config.speed_window_seconds)[:, 0]
    relative = velocity - ground  # px/s
    depth = points[..., 2]
    if up is None:
        return np.linalg.norm(relative, axis=-1) * depth / focal
    return np.linalg.norm(_onto_ground(relative, points, np.asarray(up, dtype=np.float64), focal,
                                       config.max_foreshortening), axis=-1)


def _onto_ground(image_velocity: np.ndarray, points: np.ndarray, up: np.ndarray, focal: float,
                 max_gain: float) -> np.ndarray:
    """Velocities (..., 2) in metres per second on the plane through points (..., 3) with normal `up` whose
    projections move at image_velocity (..., 2) px/s (a pinhole of focal length `focal`); directions the view
    foreshortens more than max_gain times (relative to the least foreshortened) are amplified only max_gain times."""
    up = up / np.linalg.norm(up)
    ray = points / np.linalg.norm(points, axis=-1, keepdims=True)
    across = np.cross(up, ray)
    across /= np.maximum(np.linalg.norm(across, axis=-1, keepdims=True), 1e-12)
    along = np.cross(across, up)  # on the ground, away from the camera
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    jac = np.zeros(points.shape[:-1] + (2, 3))  # d(pixel)/d(point) of the pinhole
    jac[..., 0, 0] = jac[..., 1, 1] = focal / z
    jac[..., 0, 2] = -focal * x / z ** 2
    jac[..., 1, 2] = -focal * y / z ** 2
    basis = np.stack([across, along], axis=-1)  # (..., 3, 2)
    m = jac @ basis  # (..., 2, 2): image motion per metre along the ground
    u, sigma, vt = np.linalg.svd(np.nan_to_num(m))
    floor = sigma[..., :1] / max_gain
    inverse = np.swapaxes(vt, -1, -2) @ (np.swapaxes(u, -1, -2) / np.maximum(sigma, floor)[..., :, None])
    return np.einsum("...ij,...j->...i", inverse, image_velocity)
