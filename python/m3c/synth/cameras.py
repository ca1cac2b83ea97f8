"""Metric, known camera paths for synthetic sequences, each aimed at the people it films.

Kinds: static (tripod), pan (pan/tilt from a fixed point), follow (behind a walker), tracking (a dolly beside a
walker or runner, parallel to their motion), orbit (around the group), handheld (an operator walking past, with
gait bob and shake), high (a high viewpoint looking down 30-45 degrees); beyond the default set, still (a handheld
camera held by someone standing: hand shake, breathing and a slow drift under STILL_MAX_TRAVEL_M, aimed at the
group). Horizontal field of view 40-75 degrees,
camera height 1.2-3 m (the high viewpoint rises further when the group does not fit). Each path backs off until
the people it films stay in the image.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from m3c.camera import UP, look_at, project, to_camera

CAMERA_KINDS = ("static", "pan", "follow", "tracking", "orbit", "handheld", "high")
# Kinds beyond the default benchmark set (its figures stay comparable): still, a handheld camera held by someone
# standing: shake and a slow drift within STILL_MAX_TRAVEL_M of where it started, no travel.
EXTRA_CAMERA_KINDS = ("still",)
STILL_MAX_TRAVEL_M = 0.3
AIM_HEIGHT = 0.9
# Joints that must stay in view: head, wrists, ankles, feet.
FRAMING_JOINTS = (15, 20, 21, 7, 8, 10, 11)


def ou_noise(rng, n: int, dim: int, std: float, tau_frames: float) -> np.ndarray:
    """Ornstein-Uhlenbeck noise (n, dim) with stationary std `std` and correlation time tau (frames)."""
    a = np.exp(-1.0 / max(tau_frames, 1e-6))
    out = np.zeros((n, dim))
    out[0] = std * rng.normal(size=dim)
    for i in range(1, n):
        out[i] = a * out[i - 1] + std * np.sqrt(1 - a * a) * rng.normal(size=dim)
    return out


def _smooth(x: np.ndarray, frames: int) -> np.ndarray:
    return uniform_filter1d(x, size=max(1, int(frames)), axis=0, mode="nearest")


def _horizontal(v: np.ndarray) -> np.ndarray:
    v = np.array(v, dtype=np.float64)
    v[..., 1] = 0.0
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def _roll(pose: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return out


def _in_view(world_from_cam, intrinsics, points, width, height, margin=0.04) -> float:
    """Fraction of (frame, point) pairs inside the image with a margin; points (n, K, 3)."""
    cam = to_camera(points, world_from_cam)
    z = cam[..., 2]
    u, v = np.moveaxis(project(cam, intrinsics), -1, 0)
    ok = (
        (z > 0.3)
        & (u > margin * width)
        & (u < (1 - margin) * width)
        & (v > margin * height)
        & (v < (1 - margin) * height)
    )
    return float(ok.mean())


def camera_path(
    kind: str, joints: np.ndarray, fps: float, image_size, rng
) -> tuple[np.ndarray, np.ndarray, dict]:
    """world_from_cam (n, 4, 4), intrinsics (4,) and a description, for people's world joints (P, n, 24, 3).
    follow and tracking film person 0 (the walker); the other kinds the whole group."""
    if kind not in CAMERA_KINDS + EXTRA_CAMERA_KINDS:
        kinds = ", ".join(CAMERA_KINDS + EXTRA_CAMERA_KINDS)
        raise ValueError(f"unknown camera kind {kind!r}; choose from {kinds}")
    width, height = (int(v) for v in image_size)
    n = joints.shape[1]
    hfov = np.radians(rng.uniform(40.0, 75.0))
    focal = 0.5 * width / np.tan(hfov / 2)
    intrinsics = np.array([focal, focal, width / 2, height / 2])
    t = np.arange(n) / fps
    pelvis = joints[:, :, 0]
    group = _smooth(pelvis.mean(axis=0), fps)
    group[:, 1] = AIM_HEIGHT
    walker = _smooth(pelvis[0], fps)
    walker[:, 1] = AIM_HEIGHT
    subjects = joints[:1] if kind in ("follow", "tracking") else joints
    framing = subjects[:, :, list(FRAMING_JOINTS)].transpose(1, 0, 2, 3).reshape(n, -1, 3)
    phi0 = rng.uniform(0, 2 * np.pi)
    side = rng.choice([-1.0, 1.0])
    cam_height = rng.uniform(1.2, 2.0)
    aim_jitter = ou_noise(rng, n, 3, 0.015, 0.5 * fps)
    shake = ou_noise(rng, n, 3, 0.008, 0.3 * fps)
    roll = np.zeros(n)
    info = {"kind": kind, "hfov_deg": float(np.degrees(hfov))}

    if kind == "follow":
        velocity = np.gradient(_smooth(walker, fps), axis=0) * fps
        heading = _horizontal(_smooth(velocity, fps))
        overall = _horizontal(walker[-1] - walker[0])
        slow = np.linalg.norm(velocity[:, [0, 2]], axis=-1) < 0.2
        heading[slow] = overall
        heading = _horizontal(_smooth(heading, fps))
        bob = np.stack([0.015 * np.sin(2 * np.pi * 0.9 * t), 0.02 * np.sin(2 * np.pi * 1.8 * t), 0 * t], 1)
        base = rng.uniform(3.0, 4.5)
        cam_height = rng.uniform(1.5, 1.8)
        roll = np.radians(0.8) * ou_noise(rng, n, 1, 1.0, 0.4 * fps)[:, 0]

        def build(scale):
            eye = walker - scale * base * heading + UP * (cam_height - AIM_HEIGHT) + bob + shake
            return eye, walker + 0.5 * heading + aim_jitter
    elif kind == "tracking":
        along = _horizontal(walker[-1] - walker[0])
        if np.linalg.norm(walker[-1] - walker[0]) < 0.3:
            along = _horizontal(np.array([np.sin(phi0), 0.0, np.cos(phi0)]))
        across = side * np.cross(UP, along)
        middle = walker.mean(axis=0)
        dolly = middle + ((walker - middle) @ along)[:, None] * along  # the walker's progress along the rail
        base = rng.uniform(4.0, 6.0)
        cam_height = rng.uniform(1.2, 1.6)

        def build(scale):
            eye = dolly + scale * base * across + UP * (cam_height - AIM_HEIGHT) + 0.3 * shake
            return eye, walker + 0.3 * aim_jitter
    elif kind == "orbit":
        omega = side * rng.uniform(0.25, 0.45)
        base = rng.uniform(4.5, 6.0)
        cam_height = rng.uniform(1.4, 2.2)

        def build(scale):
            ring = np.stack([np.sin(phi0 + omega * t), 0 * t, np.cos(phi0 + omega * t)], 1)
            return group + scale * base * ring + UP * (
                cam_height - AIM_HEIGHT
            ) + 0.5 * shake, group + aim_jitter
    elif kind == "handheld":
        direction = _horizontal(np.array([np.sin(phi0), 0.0, np.cos(phi0)]))
        across = np.cross(UP, direction)
        speed = rng.uniform(0.5, 0.9)
        base = rng.uniform(4.0, 6.0)
        cam_height = rng.uniform(1.5, 1.8)
        bob = np.stack([0.015 * np.sin(2 * np.pi * 0.9 * t), 0.025 * np.sin(2 * np.pi * 1.8 * t), 0 * t], 1)
        walk = (t - t.mean())[:, None] * speed * direction
        shake = ou_noise(rng, n, 3, 0.012, 0.25 * fps)
        aim_jitter = ou_noise(rng, n, 3, 0.03, 0.3 * fps)
        roll = np.radians(1.5) * ou_noise(rng, n, 1, 1.0, 0.3 * fps)[:, 0]
        centre = group.mean(axis=0)

        def build(scale):
            eye = centre + scale * base * across + walk + UP * (cam_height - AIM_HEIGHT) + bob + shake
            return eye, group + aim_jitter
    elif kind == "still":
        ray = np.array([np.sin(phi0), 0.0, np.cos(phi0)])
        centre = pelvis.reshape(-1, 3).mean(axis=0)
        centre[1] = AIM_HEIGHT
        base = rng.uniform(3.5, 6.0)
        cam_height = rng.uniform(1.4, 1.7)
        # Hand shake (1 cm, fast), breathing (1 cm at 0.25 Hz) and a drift of the stance (up to 0.1 m a second):
        # kept within STILL_MAX_TRAVEL_M of the start.
        drift = _smooth(np.cumsum(ou_noise(rng, n, 3, 0.004, 2.0 * fps), axis=0) * [1.0, 0.3, 1.0], fps)
        breathe = np.stack([0 * t, 0.01 * np.sin(2 * np.pi * 0.25 * t + phi0), 0 * t], 1)
        wobble = ou_noise(rng, n, 3, 0.01, 0.15 * fps) + drift + breathe
        reach = np.linalg.norm(wobble - wobble[0], axis=1).max()
        wobble = wobble[0] + (wobble - wobble[0]) * min(1.0, 0.9 * STILL_MAX_TRAVEL_M / max(reach, 1e-9))
        aim_jitter = ou_noise(rng, n, 3, 0.03, 0.3 * fps)
        roll = np.radians(1.0) * ou_noise(rng, n, 1, 1.0, 0.3 * fps)[:, 0]
        offset = ray * base + UP * (cam_height - AIM_HEIGHT)
        info["max_travel_m"] = float(np.linalg.norm(wobble - wobble[0], axis=1).max())

        def build(scale):
            return centre + scale * offset + wobble, _smooth(group, fps) + aim_jitter
    else:  # static, pan, high: a fixed point
        centre = pelvis.reshape(-1, 3).mean(axis=0)
        centre[1] = AIM_HEIGHT
        ray = np.array([np.sin(phi0), 0.0, np.cos(phi0)])
        if kind == "high":
            tilt = np.radians(rng.uniform(30.0, 45.0))
            cam_height = rng.uniform(2.6, 3.0)
            base = (cam_height - AIM_HEIGHT) / np.tan(tilt)
            info["tilt_deg"] = float(np.degrees(tilt))
            offset = ray * base + UP * (cam_height - AIM_HEIGHT)
        else:
            base = rng.uniform(5.0, 7.0) if kind == "static" else rng.uniform(3.5, 5.0)
            offset = ray * base + UP * (cam_height - AIM_HEIGHT)

        def build(scale):
            eye = np.repeat((centre + scale * offset)[None], n, 0)
            if kind == "static":
                return eye, np.repeat(centre[None], n, 0)
            follow = _smooth(group, 2 * fps) if kind == "high" else group
            return eye, follow + (0.3 if kind == "high" else 1.0) * aim_jitter

    scale = 1.0
    for _ in range(30):
        eye, aim = build(scale)
        poses = np.stack([_roll(look_at(e, a), r) for e, a, r in zip(eye, aim, roll)])
        if _in_view(poses, intrinsics, framing, width, height) >= 0.97:
            break
        scale *= 1.1
    info.update({"distance_scale": float(scale), "height_m": float(np.mean(poses[:, 1, 3]))})
    return poses, intrinsics, info
