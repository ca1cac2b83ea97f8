"""Virtual cameras for training the world regressor, as WHAM is trained: a motion-capture window seen through
a random camera (height, distance, focal length and one of five motions), its COCO-17 keypoints projected
through m3c.camera and corrupted the way M3C's detector errs (m3c.training.detector_errors), with occlusions
and truncation.

Cameras (M3C's world, y up; OpenCV cameras, world_from_cam (L, 4, 4)):
    static    fixed, aimed at the window's mean pelvis
    pan       fixed, turning to follow the pelvis (smoothed, so it lags)
    follow    moving with the smoothed pelvis at a fixed offset, aimed at it
    orbit     circling the smoothed pelvis at omega (deg/s, either sense), aimed at it
    handheld  static or follow, with AR(1) rotational shake and positional jitter
Every camera also has a constant aim offset (the person off-centre, often cut by the image's edge). The
distance is drawn (log-uniformly) so that a 1.7 m person spans min_fill..max_fill of the image height.

Detector errors, per window (box side s in pixels):
    box       centre += s * AR(1)(mean, std, lag1) per axis; side *= exp(AR(1)(mean, std, lag1)), from the
              true keypoints' bounding box (inside the image and in front of the camera)
    keypoint  k += s * m_j(u) * direction, with (direction, u) from a unit 2D AR(1) Gaussian g (lag1 of joint
              j): u = 1 - exp(-|g|^2 / 2) (|g|'s Rayleigh CDF) mapped through the joint's measured error
              quantiles m_j, so the errors have the measured distribution and drift as slowly as measured
    missing   a frame drops every keypoint with the joints' smallest missing rate; joint j is then dropped
              with the rest of its rate, by thresholding an AR(1) Gaussian (lag1 0.8: misses come in runs)
    occlusion with occlusion_prob, a body part (arms, legs, left or right side, lower body) masked over a
              random interval of occlusion_length of the window
    truncated keypoints outside the image or behind the camera are masked
Masked keypoints get confidence 0 (below WHAM's 0.3), the others 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from m3c.camera import UP, project, to_camera
from m3c.training.detector_errors import load_detector_errors

MOTIONS = ("static", "pan", "follow", "orbit", "handheld")
# COCO-17 body parts an occluder hides.
OCCLUDED_PARTS = ((5, 7, 9, 6, 8, 10), (11, 13, 15, 12, 14, 16), (5, 7, 9, 11, 13, 15),
                  (6, 8, 10, 12, 14, 16), (13, 14, 15, 16), (9, 10), (15, 16))
PERSON_HEIGHT = 1.7  # m, for the distance range


@dataclass
class VirtualCameraConfig:
    height: tuple = (0.3, 4.5)              # camera height above the ground, m
    hfov_deg: tuple = (35.0, 80.0)          # horizontal field of view (the longer image edge)
    image_size: tuple = (960, 540)          # landscape; portrait with portrait_prob
    portrait_prob: float = 0.2
    min_fill: float = 0.15                  # the person's share of the image height, bounds for the distance
    max_fill: float = 0.9
    min_distance: float = 1.5               # m
    orbit_speed_deg: tuple = (5.0, 40.0)    # deg/s
    follow_smoothing: float = 0.9           # exponential smoothing of the pelvis the cameras track
    shake_deg: float = 1.0                  # handheld: rotational shake (std of each angle), lag1 0.9
    jitter_m: float = 0.02                  # handheld: positional jitter (std), lag1 0.9
    aim_offset: float = 0.3                 # constant aim offset, up to this share of the half field of view
    occlusion_prob: float = 0.3
    occlusion_length: tuple = (0.1, 0.6)


def ar1(rng: np.random.Generator, n: int, shape, lag1) -> np.ndarray:
    """(n, *shape) stationary AR(1) Gaussian noise with unit variance and lag-1 correlation lag1 (a number, or
    an array broadcasting against shape): x[0] = e[0], x[t] = lag1 x[t-1] + sqrt(1 - lag1^2) e[t]."""
    shape = tuple(np.atleast_1d(shape))
    lag1 = np.broadcast_to(np.clip(np.asarray(lag1, dtype=np.float64), 0.0, 0.999), shape)
    innovation = rng.standard_normal((n, *shape))
    innovation[1:] *= np.sqrt(1.0 - lag1 ** 2)
    out = innovation
    for t in range(1, n):               # the recursion itself: n vector steps (a weight matrix is n^2 k)
        out[t] += lag1 * out[t - 1]
    return out


def _smooth(x: np.ndarray, a: float) -> np.ndarray:
    out = x.copy()
    for t in range(1, len(x)):
        out[t] = a * out[t - 1] + (1 - a) * x[t]
    return out


def _rotation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(..., 3, 3) camera-frame rotations: yaw about the camera's y, pitch about x, roll about z (radians)."""
    from scipy.spatial.transform import Rotation

    angles = np.stack(np.broadcast_arrays(yaw, pitch, roll), axis=-1)
    return Rotation.from_euler("YXZ", angles.reshape(-1, 3)).as_matrix().reshape(*angles.shape[:-1], 3, 3)


def sample_camera(rng: np.random.Generator, pelvis: np.ndarray, fps: float, config: VirtualCameraConfig,
                  motion: str | None = None) -> dict:
    """A virtual camera for a window whose pelvis moves along `pelvis` (L, 3) in the world (y up, ground y =
    0). Returns world_from_cam (L, 4, 4), intrinsics [fx, fy, cx, cy], image_size (width, height), motion."""
    n = len(pelvis)
    motion = motion or MOTIONS[rng.integers(len(MOTIONS))]
    if motion not in MOTIONS:
        raise ValueError(f"unknown camera motion {motion!r}; choose from {MOTIONS}")
    width, height = config.image_size
    if rng.random() < config.portrait_prob:
        width, height = height, width
    hfov = np.radians(rng.uniform(*config.hfov_deg))
    focal = max(width, height) / 2 / np.tan(hfov / 2)
    near = max(config.min_distance, focal * PERSON_HEIGHT / (config.max_fill * height))
    far = max(near * 1.01, focal * PERSON_HEIGHT / (config.min_fill * height))
    distance = float(np.exp(rng.uniform(np.log(near), np.log(far))))
    cam_height = rng.uniform(*config.height)
    horizontal = np.sqrt(max(distance ** 2 - (cam_height - pelvis[0, 1]) ** 2, 0.25))
    azimuth = rng.uniform(0, 2 * np.pi)
    tracked = _smooth(pelvis, config.follow_smoothing)
    base = "static" if motion == "handheld" and rng.random() < 0.5 else ("follow" if motion == "handheld"
                                                                          else motion)
    offset = horizontal * np.array([np.cos(azimuth), 0.0, np.sin(azimuth)])
    eye0 = np.array([pelvis[0, 0], cam_height, pelvis[0, 2]]) + offset
    t = np.arange(n) / fps
    if base == "static":
        eyes = np.repeat(eye0[None], n, axis=0)
        targets = np.repeat(pelvis.mean(0, keepdims=True), n, axis=0)
    elif base == "pan":
        eyes, targets = np.repeat(eye0[None], n, axis=0), tracked
    elif base == "follow":
        shift = tracked - tracked[:1]
        shift[:, 1] = 0.0
        eyes, targets = eye0 + shift, tracked
    else:  # orbit
        omega = np.radians(rng.uniform(*config.orbit_speed_deg)) * rng.choice([-1.0, 1.0])
        angle = azimuth + omega * t
        eyes = tracked * [1.0, 0.0, 1.0] + np.stack([horizontal * np.cos(angle), np.full(n, cam_height),
                                                     horizontal * np.sin(angle)], axis=1)
        targets = tracked
    if motion == "handheld":
        eyes = eyes + config.jitter_m * ar1(rng, n, 3, 0.9)
    poses = look_at_many(eyes, targets)
    half = config.aim_offset * hfov / 2
    shake = np.radians(config.shake_deg) * ar1(rng, n, 3, 0.9) if motion == "handheld" else np.zeros((n, 3))
    aim = _rotation(rng.uniform(-half, half) + shake[:, 0],
                    rng.uniform(-half, half) * height / max(width, height) + shake[:, 1], shake[:, 2])
    poses[:, :3, :3] = poses[:, :3, :3] @ aim
    return {"world_from_cam": poses, "intrinsics": np.array([focal, focal, width / 2, height / 2]),
            "image_size": (int(width), int(height)), "motion": motion}


def look_at_many(eyes: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """m3c.camera.look_at for each row of eyes, targets (L, 3): world_from_cam (L, 4, 4), in one go (the per-frame
    calls were half of a training batch's time)."""
    z = targets - eyes
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, np.asarray(UP, dtype=np.float64))
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    poses = np.tile(np.eye(4), (len(eyes), 1, 1))
    poses[:, :3, :3] = np.stack([x, y, z], axis=-1)
    poses[:, :3, 3] = eyes
    return poses


def project_keypoints(points_in_world: np.ndarray, world_from_cam: np.ndarray,
                      intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(L, K, 3) world points seen by the window's cameras (L, 4, 4): (pixels (L, K, 2), depth (L, K))."""
    cam = to_camera(points_in_world, world_from_cam)
    return project(cam, intrinsics), cam[..., 2]


class DetectorErrors:
    """The measured error model (m3c.training.detector_errors) as a sampler."""

    def __init__(self, model: dict | None = None):
        model = model or load_detector_errors()
        self.quantiles = np.asarray(model["quantiles"])
        self.error_quantiles = np.asarray(model["error_quantiles"])        # (17, Q) box sides
        self.lag1 = np.asarray(model["error_lag1"])
        missing = np.asarray(model["missing_rate"])
        self.frame_missing = float(missing.min())
        self.joint_missing = np.clip((missing - self.frame_missing) / (1 - self.frame_missing), 0.0, 0.99)
        self.box_centre, self.box_log_side = model["box_centre"], model["box_log_side"]

    def corrupt(self, rng: np.random.Generator, pixels: np.ndarray, depth: np.ndarray, image_size,
                config: VirtualCameraConfig) -> dict:
        """Detections of true keypoints pixels (L, 17, 2) at depth (L, 17) in an image (width, height).
        Returns keypoints (L, 17, 2), confidence (L, 17) (0 masked, 1 reported), box (L, 3) centre x, y and
        side (pixels), and the masks truncated / occluded / missing (L, 17)."""
        n, k = pixels.shape[:2]
        width, height = image_size
        with np.errstate(invalid="ignore"):
            inside = ((depth > 0.1) & (pixels[..., 0] >= 0) & (pixels[..., 0] < width) & (pixels[..., 1] >= 0)
                      & (pixels[..., 1] < height))
        lo = np.where(inside[..., None], pixels, np.inf).min(1)
        hi = np.where(inside[..., None], pixels, -np.inf).max(1)
        has_box = inside.sum(1) >= 2
        if not has_box.any():
            lo = hi = np.tile([[width / 2, height / 2]], (n, 1))
            has_box[:] = True
        index = np.where(has_box, np.arange(n), -1)
        index = np.maximum.accumulate(index)
        first = np.argmax(has_box)
        index[index < 0] = first                              # frames before the first box take it
        lo, hi = lo[index], hi[index]
        side = np.maximum((hi - lo).max(1), 16.0)
        bc, bs = self.box_centre, self.box_log_side
        side = side * np.exp(bs["mean"] + bs["std"] * ar1(rng, n, 1, bs["lag1"])[:, 0])
        centre = (lo + hi) / 2 + side[:, None] * (np.asarray(bc["mean"]) + np.asarray(bc["std"])
                                                  * ar1(rng, n, 2, bc["lag1"]))
        g = ar1(rng, n, (k, 2), self.lag1[:, None].repeat(2, -1))
        radius = np.linalg.norm(g, axis=-1)
        u = 1.0 - np.exp(-radius ** 2 / 2)
        magnitude = np.stack([np.interp(u[:, j], self.quantiles, self.error_quantiles[j])
                              for j in range(k)], 1)
        direction = g / np.maximum(radius, 1e-9)[..., None]
        keypoints = (np.where(np.isfinite(pixels), pixels, 0.0)
                     + side[:, None, None] * magnitude[..., None] * direction)
        frame_drop = rng.random(n) < self.frame_missing
        missing = frame_drop[:, None] | (ar1(rng, n, k, 0.8) < ndtri(np.maximum(self.joint_missing, 1e-6)))
        occluded = np.zeros((n, k), dtype=bool)
        if rng.random() < config.occlusion_prob:
            part = list(OCCLUDED_PARTS[rng.integers(len(OCCLUDED_PARTS))])
            length = max(1, round(rng.uniform(*config.occlusion_length) * n))
            start = rng.integers(0, n - length + 1)
            occluded[start:start + length, part] = True
        confidence = (inside & ~missing & ~occluded).astype(np.float64)
        return {"keypoints": keypoints, "confidence": confidence,
                "box": np.concatenate([centre, side[:, None]], axis=1), "truncated": ~inside,
                "occluded": occluded, "missing": missing}
