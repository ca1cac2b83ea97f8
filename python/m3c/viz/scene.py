"""Frames of the result videos: bodies over the input frame (overlay) and the whole scene from a virtual camera
(world view: ground, people, the video camera's frustum and path). World frame y up; cameras OpenCV."""

from __future__ import annotations

import numpy as np

from m3c.camera import look_at, project, to_camera, world_to_image
from m3c.ground.tracks import track_poses
from m3c.viz.raster import Mesh, render

# One colour per track id (RGB, [0, 1]): well separated hues, readable over video.
PALETTE = np.array([
    [0.30, 0.60, 0.95], [0.95, 0.45, 0.25], [0.35, 0.80, 0.40], [0.85, 0.35, 0.75], [0.95, 0.80, 0.25],
    [0.30, 0.85, 0.85], [0.65, 0.45, 0.95], [0.95, 0.55, 0.60], [0.60, 0.75, 0.30], [0.75, 0.60, 0.45],
])


def track_colour(track_id: int) -> np.ndarray:
    return PALETTE[int(track_id) % len(PALETTE)]


def overlay_frame(frame: np.ndarray, bodies: list[tuple[np.ndarray, int]], faces: np.ndarray,
                  world_from_cam: np.ndarray, intrinsics, alpha: float = 0.8) -> np.ndarray:
    """bodies: (vertices in the world (V, 3), track id). Returns the frame with the shaded meshes over it."""
    meshes = [Mesh(to_camera(v, world_from_cam), faces, track_colour(tid)) for v, tid in bodies]
    height, width = frame.shape[:2]
    image, _ = render(meshes, intrinsics, width, height, background=frame, alpha=alpha)
    return image


def draw_hands(frame: np.ndarray, hands: list[tuple[np.ndarray, int]], world_from_cam: np.ndarray,
               intrinsics) -> np.ndarray:
    """hands: (world points 2 x 21 x 3 in MediaPipe's order, NaN where no hand; track id). Draws each hand's
    bones (m3c.body.hands.MEDIAPIPE_HAND_BONES) in a lighter shade of the track's colour, in place; returns
    it."""
    import cv2

    from m3c.body.hands import MEDIAPIPE_HAND_BONES

    height, width = frame.shape[:2]
    thickness = max(1, round(min(width, height) / 540))
    for points, tid in hands:
        colour = tuple(int(c) for c in (255 * (0.5 + 0.5 * track_colour(tid)))[::-1])  # BGR
        for hand in points:
            if not np.isfinite(hand).all():
                continue
            cam = to_camera(hand, world_from_cam)
            if np.any(cam[:, 2] <= 0.05):
                continue
            pixels = project(cam, intrinsics)
            for a, b in MEDIAPIPE_HAND_BONES:
                start = tuple(int(round(v)) for v in pixels[a])
                end = tuple(int(round(v)) for v in pixels[b])
                cv2.line(frame, start, end, colour, thickness, cv2.LINE_AA)
    return frame


def nice_step(length: float) -> float:
    """A round tile size giving about ten tiles over `length` metres (0.25, 0.5, 1, 2, 5, ...)."""
    raw = max(length / 10.0, 1e-3)
    power = 10.0 ** np.floor(np.log10(raw))
    return float(min((m * power for m in (1.0, 2.0, 2.5, 5.0, 10.0)), key=lambda s: abs(s - raw)))


class WorldView:
    """A fixed virtual camera framing every person and camera position over the whole video."""

    def __init__(self, people_points: np.ndarray, camera_centres: np.ndarray, ground_height: float,
                 width: int = 960, height: int = 540, yaw_deg: float = 35.0, elevation_deg: float = 30.0):
        points = np.concatenate([people_points.reshape(-1, 3), camera_centres.reshape(-1, 3)])
        points = points[np.isfinite(points).all(axis=1)]
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.centre = (lo + hi) / 2
        self.centre[1] = ground_height + 0.8
        radius = max(np.linalg.norm(hi[[0, 2]] - lo[[0, 2]]) / 2, 1.5)
        self.width, self.height = width, height
        focal = float(np.hypot(width, height)) * 0.6  # a wide lens (~77 degrees diagonal)
        self.intrinsics = np.array([focal, focal, width / 2, height / 2])
        # Far enough that a disc of `radius` around the centre fits the narrower field of view.
        distance = 1.15 * radius * focal / (min(width, height) / 2)
        yaw, elevation = np.radians(yaw_deg), np.radians(elevation_deg)
        direction = np.array([np.sin(yaw) * np.cos(elevation), np.sin(elevation), -np.cos(yaw) * np.cos(elevation)])
        self.pose = look_at(self.centre + distance * direction, self.centre)
        self.ground_height = ground_height
        span = 2 * radius + 2.0
        self.tile = nice_step(span)
        self.ground = self._ground_mesh(lo, hi)

    def _ground_mesh(self, lo: np.ndarray, hi: np.ndarray) -> Mesh:
        tile = self.tile
        x0, x1 = np.floor((lo[0] - 1.0) / tile) * tile, np.ceil((hi[0] + 1.0) / tile) * tile
        z0, z1 = np.floor((lo[2] - 1.0) / tile) * tile, np.ceil((hi[2] + 1.0) / tile) * tile
        xs, zs = np.arange(x0, x1 + tile / 2, tile), np.arange(z0, z1 + tile / 2, tile)
        gx, gz = np.meshgrid(xs, zs, indexing="ij")
        vertices = np.stack([gx, np.full_like(gx, self.ground_height), gz], axis=-1).reshape(-1, 3)
        nz = len(zs)
        faces, colours = [], []
        for i in range(len(xs) - 1):
            for j in range(nz - 1):
                a, b, c, d = i * nz + j, (i + 1) * nz + j, (i + 1) * nz + j + 1, i * nz + j + 1
                shade = 0.82 if (i + j) % 2 else 0.68
                faces += [[a, b, c], [a, c, d]]
                colours += [[shade, shade, shade * 0.97]] * 2
        return Mesh(vertices, np.array(faces), face_colours=np.array(colours), smooth=False, cull=False)

    def project(self, points_in_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return world_to_image(points_in_world, self.pose, self.intrinsics)

    def frame(self, bodies: list[tuple[np.ndarray, int]], faces: np.ndarray, camera_path: np.ndarray,
              current_camera: np.ndarray, video_intrinsics, video_size: tuple[int, int],
              frustum_depth: float = 0.4) -> np.ndarray:
        import cv2

        meshes = [Mesh(to_camera(self.ground.vertices, self.pose), self.ground.faces,
                       face_colours=self.ground.face_colours, smooth=False, cull=False)]
        meshes += [Mesh(to_camera(v, self.pose), faces, track_colour(tid)) for v, tid in bodies]
        background = np.full((self.height, self.width, 3), 250, np.uint8)
        image, _ = render(meshes, self.intrinsics, self.width, self.height, background=background)
        # Camera path so far and its shadow on the ground (lines are drawn over the meshes, without a depth
        # test), and a drop line from the camera to the ground, so the camera's height reads at a glance.
        shadow = camera_path.copy()
        shadow[:, 1] = self.ground_height
        self._draw_path(image, shadow, (150, 150, 150))
        drop, dz = self.project(np.stack([camera_path[-1], shadow[-1]]))
        if (dz > 0.05).all() and np.isfinite(drop).all():
            cv2.line(image, tuple(int(round(c)) for c in drop[0]), tuple(int(round(c)) for c in drop[1]),
                     (120, 120, 120), 1, cv2.LINE_AA)
        self._draw_path(image, camera_path, (40, 40, 40))
        # The video camera's frustum: its centre and the image corners at frustum_depth.
        w, h = video_size
        fx, fy, cx, cy = video_intrinsics
        corners = np.array([[(u - cx) / fx, (v - cy) / fy, 1.0] for u, v in ((0, 0), (w, 0), (w, h), (0, h))])
        frustum_cam = np.vstack([np.zeros(3), frustum_depth * corners])
        frustum = frustum_cam @ current_camera[:3, :3].T + current_camera[:3, 3]
        uv, z = self.project(frustum)
        if (z > 0.05).all() and np.isfinite(uv).all():
            p = [tuple(int(round(c)) for c in q) for q in uv]
            for k in range(1, 5):
                cv2.line(image, p[0], p[k], (30, 30, 200), 2, cv2.LINE_AA)
                cv2.line(image, p[k], p[1 + k % 4], (30, 30, 200), 2, cv2.LINE_AA)
        return image

    def _draw_path(self, image: np.ndarray, points_in_world: np.ndarray, colour) -> None:
        """One polyline through the points in front of the view camera, in one call: a frame of a long video
        draws the path so far (thousands of points), and a Python loop of cv2.line per segment made the world
        view quadratic in the video's length in Python time. Repeated pixels (a camera at rest) are dropped."""
        import cv2

        uv, z = self.project(points_in_world)
        keep = (z > 0.05) & np.isfinite(uv).all(axis=1)
        pixels = np.round(np.clip(uv[keep], -1e6, 1e6)).astype(np.int32)
        if len(pixels) < 2:
            return
        pixels = pixels[np.r_[True, (np.diff(pixels, axis=0) != 0).any(axis=1)]]
        cv2.polylines(image, [pixels.reshape(-1, 1, 2)], False, colour, 2, cv2.LINE_AA)


class BodyFrames:
    """World-frame vertices of every track at a frame, computed a chunk of frames at a time."""

    def __init__(self, model, tracks: list[dict], chunk: int = 16):
        self.model, self.tracks, self.chunk = model, tracks, chunk
        self._cache: dict[int, tuple[int, np.ndarray]] = {}

    def at(self, frame: int) -> list[tuple[np.ndarray, int]]:
        bodies = []
        for k, track in enumerate(self.tracks):
            i = frame - int(track["first_frame"])
            if not 0 <= i < int(track["num_frames"]):
                continue
            start, verts = self._cache.get(k, (-1, None))
            if verts is None or not start <= i < start + len(verts):
                start = i
                stop = min(i + self.chunk, int(track["num_frames"]))
                pose = track_poses(track)[start:stop]
                verts = self.model.forward(pose, np.asarray(track["betas"]),
                                           np.asarray(track["transl"])[start:stop]).vertices
                self._cache[k] = (start, verts)
            bodies.append((verts[i - start], int(track["track_id"])))
        return bodies
