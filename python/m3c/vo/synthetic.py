"""Synthetic sequences with known camera poses for testing and benchmarking the patch VO.

A textured box room is rendered exactly by ray-plane intersection (bilinear texture lookup, optional
supersampling against aliasing); textured rectangles ("people") move inside it and come with their masks.
Everything is numpy; frames are gray uint8, depths are the camera z of the visible surface.
Conventions: OpenCV camera (x right, y down, z forward); world y points down; world_from_cam 4x4.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter

ROOM_MIN = np.array([-3.0, -1.6, -3.0])
ROOM_MAX = np.array([3.0, 1.4, 9.0])


@dataclass
class SyntheticSequence:
    frames: np.ndarray          # (T, H, W) uint8
    masks: np.ndarray           # (T, H, W) bool, True where an occluder is visible
    depths: np.ndarray          # (T, H, W) float32, camera z of the visible surface, metres
    world_from_cam: np.ndarray  # (T, 4, 4) float64
    intrinsics: np.ndarray      # (4,) fx, fy, cx, cy

    @property
    def camera_centres(self) -> np.ndarray:
        return self.world_from_cam[:, :3, 3]


@dataclass
class Occluder:
    """A textured upright rectangle facing -z (towards a camera looking +z), centre given per frame."""
    centre: Callable[[int], np.ndarray]
    width: float = 0.6
    height: float = 1.7
    texture: np.ndarray = field(default_factory=lambda: make_texture(256, seed=99, contrast=2.0))
    texel: float = 0.01


def make_texture(size: int, seed: int, contrast: float = 1.0) -> np.ndarray:
    """Periodic multi-scale noise texture (size, size) float32 in [0, 255]; contrast scales the amplitude."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((size, size))
    for sigma, weight in ((12.0, 1.0), (4.0, 0.6), (1.5, 0.35)):
        layer = gaussian_filter(rng.standard_normal((size, size)), sigma, mode="wrap")
        tex += weight * layer / layer.std()
    tex = 128.0 + 30.0 * contrast * tex / tex.std()
    return np.clip(tex, 0.0, 255.0).astype(np.float32)


def _sample(texture: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Bilinear lookup with wrap-around at texel coordinates (s = column, t = row)."""
    n_rows, n_cols = texture.shape
    s0 = np.floor(s)
    t0 = np.floor(t)
    fs = s - s0
    ft = t - t0
    c0 = s0.astype(np.int64) % n_cols
    r0 = t0.astype(np.int64) % n_rows
    c1 = (c0 + 1) % n_cols
    r1 = (r0 + 1) % n_rows
    top = texture[r0, c0] * (1 - fs) + texture[r0, c1] * fs
    bottom = texture[r1, c0] * (1 - fs) + texture[r1, c1] * fs
    return top * (1 - ft) + bottom * ft


def look_rotation(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """world_from_cam rotation: yaw about world y (down), then pitch about x, then roll about z."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


class RoomRenderer:
    """Exact renderer of the textured box room plus occluders."""

    def __init__(self, width: int, height: int, intrinsics: np.ndarray | None = None, supersample: int = 2,
                 seed: int = 0, texel: float = 0.015):
        self.width, self.height = width, height
        if intrinsics is None:
            f = float(np.hypot(width, height))
            intrinsics = np.array([f, f, width / 2.0, height / 2.0])
        self.intrinsics = np.asarray(intrinsics, dtype=np.float64)
        self.supersample = int(supersample)
        self.texel = texel
        # (axis, offset, in-plane axes (column, row), texture, brightness offset)
        self.planes = []
        k = 0
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            for offset in (ROOM_MIN[axis], ROOM_MAX[axis]):
                tex = make_texture(512, seed=seed * 10 + k)
                self.planes.append((axis, offset, others, tex, 8.0 * (k % 3) - 8.0))
                k += 1
        s = self.supersample
        fx, fy, cx, cy = self.intrinsics
        u = (np.arange(width * s) + 0.5) / s - 0.5
        v = (np.arange(height * s) + 0.5) / s - 0.5
        uu, vv = np.meshgrid(u, v)
        self._rays_cam = np.stack([(uu - cx) / fx, (vv - cy) / fy, np.ones_like(uu)], axis=-1).reshape(-1, 3)

    def render(self, world_from_cam: np.ndarray, occluders: list[tuple[Occluder, np.ndarray]] = ()):
        """Returns (gray uint8 (H, W), mask bool (H, W), depth float32 (H, W)) for one camera pose."""
        rot = world_from_cam[:3, :3]
        centre = world_from_cam[:3, 3]
        if not (np.all(centre > ROOM_MIN) and np.all(centre < ROOM_MAX)):
            raise ValueError(f"camera centre {centre} must lie inside the room {ROOM_MIN} .. {ROOM_MAX}")
        dirs = self._rays_cam @ rot.T  # world directions; camera z of a hit at ray parameter t is t
        n = dirs.shape[0]
        best_t = np.full(n, np.inf)
        best_plane = np.full(n, -1)
        for i, (axis, offset, _, _, _) in enumerate(self.planes):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (offset - centre[axis]) / dirs[:, axis]
            t = np.where(t > 1e-9, t, np.inf)
            closer = t < best_t
            best_t[closer] = t[closer]
            best_plane[closer] = i
        intensity = np.empty(n)
        for i, (axis, offset, (ca, ra), tex, brightness) in enumerate(self.planes):
            sel = best_plane == i
            if not np.any(sel):
                continue
            hit = centre + best_t[sel, None] * dirs[sel]
            intensity[sel] = _sample(tex, hit[:, ca] / self.texel, hit[:, ra] / self.texel) + brightness
        occluded = np.zeros(n, dtype=bool)
        for occ, occ_centre in occluders:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (occ_centre[2] - centre[2]) / dirs[:, 2]
            hit = centre + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs
            local_x = hit[:, 0] - occ_centre[0] + occ.width / 2
            local_y = hit[:, 1] - occ_centre[1] + occ.height / 2
            inside = ((t > 1e-9) & (t < best_t) & (local_x >= 0) & (local_x <= occ.width) & (local_y >= 0)
                      & (local_y <= occ.height))
            if np.any(inside):
                intensity[inside] = _sample(occ.texture, local_x[inside] / occ.texel,
                                            local_y[inside] / occ.texel)
                best_t[inside] = t[inside]
                occluded |= inside
        s = self.supersample
        shape = (self.height, s, self.width, s)
        gray = intensity.reshape(self.height * s, self.width * s).reshape(shape).mean(axis=(1, 3))
        depth = best_t.reshape(self.height * s, self.width * s).reshape(shape).mean(axis=(1, 3))
        mask = occluded.reshape(self.height * s, self.width * s).reshape(shape).any(axis=(1, 3))
        return (np.clip(np.rint(gray), 0, 255).astype(np.uint8), mask, depth.astype(np.float32))


def forward_trajectory(num_frames: int, length: float = 2.5, sway: float = 0.4, yaw_amplitude: float = 0.25
                       ) -> np.ndarray:
    """(T, 4, 4) world_from_cam: forward along +z with a lateral sway, gentle yaw and pitch."""
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    for i in range(num_frames):
        s = i / max(num_frames - 1, 1)
        poses[i, :3, 3] = [sway * np.sin(2 * np.pi * s), 0.1 * np.sin(4 * np.pi * s), length * s]
        poses[i, :3, :3] = look_rotation(yaw_amplitude * np.sin(2 * np.pi * s), 0.05 * np.sin(2 * np.pi * s),
                                         0.03 * np.sin(4 * np.pi * s))
    return poses


def static_trajectory(num_frames: int) -> np.ndarray:
    return np.tile(np.eye(4), (num_frames, 1, 1))


def following_occluders(world_from_cam: np.ndarray, count: int = 2, seed: int = 5) -> list[Occluder]:
    """Occluders that walk along with the camera, about 3 m ahead (nearly still in the image: the case that
    breaks VO), with a high-contrast texture so an unmasked gradient sampler favours them."""
    rng = np.random.default_rng(seed)
    occluders = []
    for k in range(count):
        offset = np.array([(-0.6 if k % 2 == 0 else 0.55) + 0.1 * rng.standard_normal(), 0.3, 2.8 + 0.4 * k])
        phase = rng.uniform(0, 2 * np.pi)

        def centre(i: int, offset=offset, phase=phase) -> np.ndarray:
            cam_centre = world_from_cam[i, :3, 3]
            sway = np.array([0.08 * np.sin(0.3 * i + phase), 0.02 * np.sin(0.9 * i + phase), 0.0])
            return cam_centre + offset + sway

        occluders.append(Occluder(centre=centre, width=0.5, height=1.0, texel=0.004,
                                  texture=make_texture(256, seed=100 + k, contrast=2.5)))
    return occluders


def render_sequence(world_from_cam: np.ndarray, width: int = 320, height: int = 240,
                    occluders: list[Occluder] = (), noise_sigma: float = 0.0, seed: int = 0,
                    supersample: int = 1) -> SyntheticSequence:
    """Renders every pose; noise_sigma adds Gaussian pixel noise (grey levels) before quantisation."""
    renderer = RoomRenderer(width, height, supersample=supersample, seed=seed)
    rng = np.random.default_rng(seed + 1)
    T = world_from_cam.shape[0]
    frames = np.empty((T, height, width), np.uint8)
    masks = np.empty((T, height, width), bool)
    depths = np.empty((T, height, width), np.float32)
    for i in range(T):
        gray, mask, depth = renderer.render(world_from_cam[i], [(o, o.centre(i)) for o in occluders])
        if noise_sigma > 0:
            gray = np.clip(np.rint(gray + rng.normal(0.0, noise_sigma, gray.shape)), 0, 255).astype(np.uint8)
        frames[i], masks[i], depths[i] = gray, mask, depth
    return SyntheticSequence(frames, masks, depths, world_from_cam.copy(), renderer.intrinsics.copy())


def built_scene_edges(width: int, height: int, intrinsics, world_from_cam: np.ndarray, seed: int = 0,
                      camera_height: float = 1.6) -> np.ndarray:
    """A gray uint8 image of a built scene's straight edges (m3c.vo.vanishing's test scene): poles standing on
    the ground, kerbs and wall lines along the world's x and z axes on and above it, drawn anti-aliased with
    OpenCV. World y points down (as above), the ground is y = camera_height, the camera at world_from_cam."""
    import cv2

    rng = np.random.default_rng(seed)
    ground, top = camera_height, camera_height - 3.0
    edges = []
    for x, z in zip(rng.uniform(-6, 6, 14), rng.uniform(4, 14, 14)):  # poles
        edges.append(((x, ground, z), (x, top, z)))
    for z in (5.0, 7.5, 10.0, 12.5):  # lines across the view, on the ground and 3 m up
        for y in (ground, top):
            edges.append(((-6.0, y, z), (6.0, y, z)))
    for x in (-5.0, -3.0, -1.5, 1.5, 3.0, 5.0):  # lines along the view, on the ground
        edges.append(((x, ground, 3.0), (x, ground, 15.0)))
    fx, fy, cx, cy = np.asarray(intrinsics, dtype=np.float64)
    cam_from_world = np.linalg.inv(world_from_cam)
    image = np.full((height, width), 60, np.uint8)
    for a, b in edges:
        p, q = (cam_from_world[:3, :3] @ np.asarray(e) + cam_from_world[:3, 3] for e in (a, b))
        near = 0.2
        if p[2] < near and q[2] < near:
            continue
        if p[2] < near or q[2] < near:  # clip at the near plane
            s = (near - p[2]) / (q[2] - p[2])
            cut = p + s * (q - p)
            p, q = (cut, q) if p[2] < near else (p, cut)
        u0, v0 = fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy
        u1, v1 = fx * q[0] / q[2] + cx, fy * q[1] / q[2] + cy
        ok, start, end = cv2.clipLine((0, 0, width, height), (int(round(u0)), int(round(v0))),
                                      (int(round(u1)), int(round(v1))))
        if ok:
            cv2.line(image, start, end, 230, 2, cv2.LINE_AA)
    noise = rng.normal(0, 3, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)
