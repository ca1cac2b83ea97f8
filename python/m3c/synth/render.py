"""Frames of a synthetic scene: static textured meshes and people (per-face colours) through the C++
rasteriser, supersampled and box-filtered down (anti-aliased edges), with depth and per-pixel object ids."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from m3c import _core

SKY_RGB = np.array([0.72, 0.80, 0.90], dtype=np.float32)


@dataclass
class TexturedMesh:
    """A static mesh in the world: vertices (V, 3) metres, faces (F, 3), uv (V, 2) in texels of its texture."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: int  # index into the scene's textures
    cull: bool = True  # closed meshes (boxes): skip faces seen from behind
    ground: bool = False  # part of the floor (y = 0): what a glossy floor mirrors the rest in


@dataclass
class RenderedFrame:
    image: np.ndarray  # (H, W, 3) BGR uint8
    depth: np.ndarray  # (H, W) float32 camera z, inf where only sky
    ids: np.ndarray  # (H, W) int32: person index, -1 for the static scene and the sky


def camera_from_world_points(points: np.ndarray, world_from_cam: np.ndarray) -> np.ndarray:
    R, c = world_from_cam[:3, :3], world_from_cam[:3, 3]
    return (np.asarray(points, dtype=np.float64) - c) @ R


class Renderer:
    """Renders one image size; textures are uploaded once. `supersample` s renders s x s samples per pixel."""

    def __init__(
        self,
        textures: list[np.ndarray],
        width: int,
        height: int,
        supersample: int = 2,
        light_in_world=(0.35, 0.85, -0.4),
        ambient: float = 0.45,
        sky=SKY_RGB,
    ):
        if width < 8 or height < 8:
            raise ValueError(f"image size must be at least 8 x 8 pixels, got {width} x {height}")
        if supersample < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        self.textures = [_core.Texture(np.asarray(t, dtype=np.float32)) for t in textures]
        self.width, self.height, self.supersample = int(width), int(height), int(supersample)
        light = np.asarray(light_in_world, dtype=np.float64)
        self.light = light / np.linalg.norm(light)
        self.ambient = float(ambient)
        self.sky = np.asarray(sky, dtype=np.float32)

    def _hi_res(self, intrinsics) -> np.ndarray:
        # Pixel centres at integers in both images: low-res u = (u_hi + 0.5) / s - 0.5.
        s = self.supersample
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        return np.array([fx * s, fy * s, cx * s + (s - 1) / 2, cy * s + (s - 1) / 2])

    def render(
        self,
        world_from_cam: np.ndarray,
        intrinsics,
        static: list[TexturedMesh],
        people: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
        full: bool = True,
        gloss: float = 0.0,
    ) -> RenderedFrame:
        """static: meshes ordered near to far where possible (objects, ground, backdrop); people: (vertices
        (V, 3) world, faces (F, 3), face_rgb (F, 3)) per person, their index is their id. full=False renders the
        people alone on the sky (for occlusion ratios), at the same resolution. gloss > 0: the floor (the ground
        meshes, y = 0) mirrors everything else with this reflectance (a polished hall floor: the people's
        reflections move on it)."""
        rgb, depth, ids = self._draw(world_from_cam, intrinsics, static, people, full, mirrored=False)
        if gloss > 0 and full:
            reflected, reflected_depth, _ = self._draw(world_from_cam, intrinsics, static, people, True,
                                                       mirrored=True)
            mirror = self._floor_pixels(world_from_cam, intrinsics, depth)[..., None] & np.isfinite(
                reflected_depth)[..., None]
            rgb = np.where(mirror, (1.0 - gloss) * rgb + gloss * reflected, rgb)
        image = np.clip(rgb[..., ::-1] * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return RenderedFrame(image, depth, ids)

    def _floor_pixels(self, world_from_cam: np.ndarray, intrinsics, depth: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels whose nearest surface is the plane y = 0 (depth where the ray meets it)."""
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u, dtype=np.float64)], axis=-1)
        dy = rays @ world_from_cam[1, :3]  # world y of each ray's direction (z = 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = -world_from_cam[1, 3] / dy
        return (z > 0) & np.isfinite(depth) & (np.abs(depth - z) < 0.01 + 0.003 * z)

    def _draw(self, world_from_cam, intrinsics, static, people, full, mirrored):
        """(rgb (H, W, 3) float RGB, depth, ids) at the output resolution; mirrored: everything but the ground
        reflected through y = 0 (winding and light reflected with it)."""
        flip = np.array([1.0, -1.0, 1.0])
        s = self.supersample
        K = self._hi_res(intrinsics)
        frame = _core.RenderFrame(self.width * s, self.height * s, self.sky)
        light = world_from_cam[:3, :3].T @ (self.light * flip if mirrored else self.light)

        def placed(vertices, faces):
            if not mirrored:
                return camera_from_world_points(vertices, world_from_cam), faces
            return (camera_from_world_points(np.asarray(vertices) * flip, world_from_cam),
                    np.ascontiguousarray(np.asarray(faces)[:, ::-1]))
        # Near to far (people, then the static meshes in the scene's order): the depth test then skips the
        # shading of most hidden fragments.
        for index, (vertices, faces, face_rgb) in enumerate(people):
            points, faces = placed(vertices, faces)
            frame.draw_coloured(
                K,
                points,
                faces,
                face_rgb,
                light,
                self.ambient,
                index,
                True,
            )
        if full:
            for mesh in static:
                if mirrored and mesh.ground:
                    continue
                points, faces = placed(mesh.vertices, mesh.faces)
                frame.draw_textured(
                    K,
                    points,
                    faces,
                    self.textures[mesh.texture],
                    mesh.uv,
                    light,
                    self.ambient,
                    -1,
                    mesh.cull,
                )
        rgb = frame.rgb
        if s > 1:  # an exact s x s box filter
            rgb = cv2.resize(rgb, (self.width, self.height), interpolation=cv2.INTER_AREA)
        # Depth and ids from the sample nearest each pixel centre.
        pick = (slice(s // 2, None, s), slice(s // 2, None, s))
        return rgb, frame.depth[pick], frame.ids[pick]
