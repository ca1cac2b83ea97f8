"""The world view that shows how people move: a chase camera framed on the people (about half the frame high,
from a raised three-quarter view, smoothed over the whole video so it never cuts), footprints where a foot is
planted (they stay: a sliding foot draws a smear, a walk a row of steps), the pelvis path as a trail, a ground
grid in metres with a scale bar, the frame's time, and the whole scene from above as an inset with the camera's
path and frustum. World frame y up, metres; cameras OpenCV.

The ground, grid, footprints and trails are drawn with OpenCV over a flat background, the bodies rasterised over
them (m3c.viz.raster); the inset is a 2D map."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from m3c.camera import look_at, to_camera
from m3c.viz.raster import Mesh, render
from m3c.viz.scene import nice_step, track_colour

PELVIS_HEIGHT = 0.9        # metres above the ground the camera looks at
FRAME_SHARE = 0.5          # a standing person's height as a share of the frame height
PERSON_HEIGHT = 1.7        # metres, for the framing
SMOOTHING_S = 1.0          # the chase camera's Gaussian smoothing (sigma, seconds)
ELEVATION_DEG = 25.0       # the chase camera above the horizontal
THREE_QUARTER_DEG = 45.0   # from the side of the travel towards its front
FOOTPRINT = (0.26, 0.10)   # length along the foot and width, metres
NEAR = 0.05
BACKGROUND = (244, 241, 236)   # BGR: the sky
GROUND = (214, 220, 222)       # BGR: the floor
GRID, GRID_MAJOR = (186, 192, 194), (150, 156, 158)


@dataclass
class TrackMotion:
    """What the world view draws of one track: frames first..first + n - 1, pelvis (n, 3), the feet's ground
    points and directions while planted (per foot: (n, 3) heel, (n, 3) toe, (n,) planted), its id."""

    track_id: int
    first_frame: int
    pelvis: np.ndarray
    heels: np.ndarray      # (2, n, 3): left, right ankle joints
    toes: np.ndarray       # (2, n, 3): left, right foot joints
    planted: np.ndarray    # (2, n) bool

    @property
    def num_frames(self) -> int:
        return len(self.pelvis)


def _fill_gaps(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per column, linear interpolation over the frames where `known` is False (held at the ends)."""
    out = values.copy()
    frames = np.arange(len(values))
    if not known.any():
        return out
    for k in range(values.shape[1]):
        out[:, k] = np.interp(frames, frames[known], values[known, k])
    return out


class ChaseView:
    """A virtual camera that follows the people: per frame world_from_cam (T, 4, 4), smoothed over time.

    people: per frame the people's pelvis positions ((k, 3) arrays, k >= 0), fps the video's frame rate.
    """

    def __init__(self, people: list[np.ndarray], camera_centres: np.ndarray, ground_height: float, fps: float,
                 width: int = 960, height: int = 540, elevation_deg: float = ELEVATION_DEG,
                 three_quarter_deg: float = THREE_QUARTER_DEG, frame_share: float = FRAME_SHARE):
        self.width, self.height, self.ground_height = width, height, ground_height
        focal = float(np.hypot(width, height)) * 0.6
        self.intrinsics = np.array([focal, focal, width / 2, height / 2])
        T = len(people)
        centre = np.zeros((T, 3))
        radius = np.zeros(T)
        seen = np.zeros(T, bool)
        for t, points in enumerate(people):
            points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
            points = points[np.isfinite(points).all(axis=1)]
            if len(points):
                seen[t] = True
                centre[t] = points.mean(axis=0)
                radius[t] = np.linalg.norm((points - centre[t])[:, [0, 2]], axis=1).max()
        if not seen.any():  # nobody: look at the ground in front of the first camera
            start = camera_centres[0] if len(camera_centres) else np.zeros(3)
            centre[:] = start + np.array([0.0, 0.0, 3.0])
            seen[:] = True
        centre = _fill_gaps(centre, seen)
        radius = _fill_gaps(radius[:, None], seen)[:, 0]
        sigma = max(SMOOTHING_S * fps, 1.0)
        centre = gaussian_filter1d(centre, sigma, axis=0, mode="nearest")
        centre[:, 1] = ground_height + PELVIS_HEIGHT
        # The view direction, one for the whole video: three-quarters from the side of the people's travel that
        # the video camera is on (a still group: from the video camera's side).
        travel = centre[-1] - centre[0]
        travel[1] = 0.0
        towards_camera = (camera_centres[0] if len(camera_centres) else centre[0] - [0, 0, 3]) - centre[0]
        towards_camera[1] = 0.0
        if np.linalg.norm(towards_camera) < 1e-6:
            towards_camera = np.array([0.0, 0.0, -1.0])
        towards_camera /= np.linalg.norm(towards_camera)
        if np.linalg.norm(travel) > 0.5:
            forward = travel / np.linalg.norm(travel)
            side = np.cross([0.0, 1.0, 0.0], forward)
            side *= np.sign(side @ towards_camera) or 1.0
            angle = np.radians(three_quarter_deg)
            horizontal = np.cos(angle) * side + np.sin(angle) * forward
        else:
            horizontal = towards_camera
        elevation = np.radians(elevation_deg)
        direction = np.cos(elevation) * horizontal + np.sin(elevation) * np.array([0.0, 1.0, 0.0])
        # Far enough that a person is frame_share of the frame high, and the group fits the frame's width.
        # Smoothed after taking the larger of the two, so the switch between them does not kink the motion.
        by_height = focal * PERSON_HEIGHT / (frame_share * height)
        by_width = focal * (radius + 0.6) / (0.4 * width)
        self.distance = gaussian_filter1d(np.maximum(by_height, by_width), sigma, mode="nearest")
        self.targets = centre
        self.poses = np.stack([look_at(c + d * direction, c) for c, d in zip(centre, self.distance)])

    def pixels_per_metre(self, t: int) -> float:
        return float(self.intrinsics[0] / self.distance[t])

    def project(self, points: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        cam = to_camera(np.asarray(points, dtype=np.float64), self.poses[t])
        z = cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = cam[..., :2] / z[..., None] * self.intrinsics[:2] + self.intrinsics[2:]
        return uv, z


def _clip_polygon(cam: np.ndarray) -> np.ndarray:
    """The polygon (k, 3) in camera coordinates cut to z >= NEAR (Sutherland-Hodgman against one plane)."""
    out = []
    for i in range(len(cam)):
        a, b = cam[i], cam[(i + 1) % len(cam)]
        a_in, b_in = a[2] >= NEAR, b[2] >= NEAR
        if a_in:
            out.append(a)
        if a_in != b_in:
            s = (NEAR - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out)


def _to_pixels(cam: np.ndarray, intrinsics) -> np.ndarray:
    uv = cam[:, :2] / cam[:, 2:3] * intrinsics[:2] + intrinsics[2:]
    return np.round(np.clip(uv, -1e5, 1e5) * 4).astype(np.int32)  # 2 bits of sub-pixel precision (shift=2)


def _segment(image, a_cam, b_cam, intrinsics, colour, thickness=1) -> None:
    import cv2

    if a_cam[2] < NEAR and b_cam[2] < NEAR:
        return
    if a_cam[2] < NEAR:
        a_cam = a_cam + (NEAR - a_cam[2]) / (b_cam[2] - a_cam[2]) * (b_cam - a_cam)
    elif b_cam[2] < NEAR:
        b_cam = b_cam + (NEAR - b_cam[2]) / (a_cam[2] - b_cam[2]) * (a_cam - b_cam)
    p = _to_pixels(np.stack([a_cam, b_cam]), intrinsics)
    cv2.line(image, tuple(p[0]), tuple(p[1]), colour, thickness, cv2.LINE_AA, shift=2)


def _darker(colour: np.ndarray, factor: float) -> tuple[int, int, int]:
    bgr = (np.asarray(colour)[::-1] * 255.0 * factor).round().astype(int)
    return tuple(int(c) for c in np.clip(bgr, 0, 255))


class ChaseFrames:
    """Draws world-view frames with a ChaseView: ground, grid, footprints, trails, bodies, the time, the inset."""

    def __init__(self, view: ChaseView, tracks: list[TrackMotion], world_from_cam: np.ndarray,
                 video_intrinsics, video_size: tuple[int, int], times: np.ndarray, inset: bool = True):
        self.view, self.tracks, self.times = view, tracks, np.asarray(times, dtype=np.float64)
        self.world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
        self.video_intrinsics, self.video_size = np.asarray(video_intrinsics, dtype=np.float64), video_size
        self.inset = inset
        self._footprints = [self._footprint_polygons(t) for t in tracks]
        span = max(float(np.ptp(view.targets[:, [0, 2]], axis=0).max()) + 8.0, 8.0)
        self.tile = 1.0 if span < 60 else nice_step(span / 4)
        self._map = _MapInset(tracks, self.world_from_cam, view.width, view.height) if inset else None

    def _footprint_polygons(self, track: TrackMotion) -> list[tuple[int, np.ndarray]]:
        """(frame, (4, 3) ground polygon) for every planted foot frame: a rectangle from heel to toe."""
        length, width = FOOTPRINT
        out = []
        h = self.view.ground_height + 0.003
        for foot in range(2):
            for i in np.flatnonzero(track.planted[foot]):
                heel, toe = track.heels[foot, i].copy(), track.toes[foot, i].copy()
                if not (np.isfinite(heel).all() and np.isfinite(toe).all()):
                    continue
                heel[1] = toe[1] = h
                along = toe - heel
                norm = np.linalg.norm(along)
                along = along / norm if norm > 1e-3 else np.array([0.0, 0.0, 1.0])
                across = np.cross([0.0, 1.0, 0.0], along)
                centre = (heel + toe) / 2
                a, c = 0.5 * max(length, norm + 0.08) * along, 0.5 * width * across
                out.append((track.first_frame + int(i),
                            np.stack([centre - a - c, centre + a - c, centre + a + c, centre - a + c])))
        out.sort(key=lambda item: item[0])
        return out

    def frame(self, t: int, bodies: list[tuple[np.ndarray, int]], faces: np.ndarray) -> np.ndarray:
        import cv2

        view = self.view
        pose, K = view.poses[t], view.intrinsics
        image = np.empty((view.height, view.width, 3), np.uint8)
        image[:] = BACKGROUND
        # The ground: a large square around the target, cut at the near plane.
        c = view.targets[t]
        size = 200.0
        corners = np.array([[c[0] - size, view.ground_height, c[2] - size], [c[0] + size, view.ground_height,
                            c[2] - size], [c[0] + size, view.ground_height, c[2] + size],
                            [c[0] - size, view.ground_height, c[2] + size]])
        polygon = _clip_polygon(to_camera(corners, pose))
        if len(polygon) >= 3:
            cv2.fillPoly(image, [_to_pixels(polygon, K).reshape(-1, 1, 2)], GROUND, cv2.LINE_AA, shift=2)
        # The grid: lines every tile metres within reach of the view, every fifth darker.
        reach = min(25.0, 2.5 * float(view.distance[t]) + 3.0)  # farther lines only crowd the horizon
        tile = self.tile
        lo = np.floor((c[[0, 2]] - reach) / tile).astype(int)
        hi = np.ceil((c[[0, 2]] + reach) / tile).astype(int)
        for axis in (0, 2):
            other = 2 - axis
            k0, k1 = (lo[0], hi[0]) if axis == 0 else (lo[1], hi[1])
            o0, o1 = (lo[1], hi[1]) if axis == 0 else (lo[0], hi[0])
            for k in range(k0, k1 + 1):
                a, b = np.zeros(3), np.zeros(3)
                a[1] = b[1] = view.ground_height
                a[axis] = b[axis] = k * tile
                a[other], b[other] = o0 * tile, o1 * tile
                cam = to_camera(np.stack([a, b]), pose)
                _segment(image, cam[0], cam[1], K, GRID_MAJOR if k % 5 == 0 else GRID, 1)
        # Footprints so far, then each pelvis path so far.
        layer = image.copy()
        for track, prints in zip(self.tracks, self._footprints):
            colour = _darker(track_colour(track.track_id), 0.7)
            polys = [_clip_polygon(to_camera(p, pose)) for frame, p in prints if frame <= t]
            polys = [_to_pixels(p, K).reshape(-1, 1, 2) for p in polys if len(p) >= 3]
            if polys:
                cv2.fillPoly(layer, polys, colour, cv2.LINE_AA, shift=2)
        cv2.addWeighted(layer, 0.75, image, 0.25, 0.0, dst=image)
        for track in self.tracks:
            upto = t - track.first_frame + 1
            if upto < 2:
                continue
            path = track.pelvis[:min(upto, track.num_frames)].copy()
            path = path[np.isfinite(path).all(axis=1)]
            path[:, 1] = view.ground_height + 0.005
            cam = to_camera(path, pose)
            cam = cam[cam[:, 2] >= NEAR]
            if len(cam) >= 2:
                cv2.polylines(image, [_to_pixels(cam, K).reshape(-1, 1, 2)], False,
                              _darker(track_colour(track.track_id), 0.55), 1, cv2.LINE_AA, shift=2)
        # The bodies over the ground.
        if bodies:
            meshes = [Mesh(to_camera(v, pose), faces, track_colour(tid)) for v, tid in bodies]
            image, _ = render(meshes, K, view.width, view.height, background=image)
        self._annotate(image, t)
        if self._map is not None:
            self._map.draw(image, t, self.video_intrinsics, self.video_size)
        return image

    def _annotate(self, image: np.ndarray, t: int) -> None:
        import cv2

        font = cv2.FONT_HERSHEY_SIMPLEX
        label = f"t = {self.times[t]:.2f} s   frame {t + 1}/{len(self.times)}"
        cv2.putText(image, label, (14, 28), font, 0.6, (40, 40, 40), 1, cv2.LINE_AA)
        # The scale bar: one metre at the people's distance, and the grid's spacing.
        px = self.view.pixels_per_metre(t)
        metres = 1.0 if px > 40 else nice_step(80.0 / px * 10)
        length = int(round(metres * px))
        x0, y0 = 14, image.shape[0] - 18
        cv2.line(image, (x0, y0), (x0 + length, y0), (40, 40, 40), 2, cv2.LINE_AA)
        for x in (x0, x0 + length):
            cv2.line(image, (x, y0 - 5), (x, y0 + 5), (40, 40, 40), 2, cv2.LINE_AA)
        cv2.putText(image, f"{metres:g} m at the people; grid {self.tile:g} m", (x0 + length + 8, y0 + 5), font,
                    0.5, (40, 40, 40), 1, cv2.LINE_AA)


class _MapInset:
    """The whole scene from above in a corner: the camera's path so far and its frustum, the people's paths and
    where they are, a scale bar."""

    def __init__(self, tracks: list[TrackMotion], world_from_cam: np.ndarray, width: int, height: int):
        self.tracks, self.poses = tracks, world_from_cam
        camera_centres = world_from_cam[:, :3, 3]
        self.cameras = camera_centres
        self.size = (max(120, width // 4), max(90, height // 4))
        points = [camera_centres[:, [0, 2]]] + [t.pelvis[:, [0, 2]] for t in tracks]
        points = np.concatenate(points)
        points = points[np.isfinite(points).all(axis=1)]
        if not len(points):
            points = np.zeros((1, 2))
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.centre = (lo + hi) / 2
        span = max(float((hi - lo).max()), 2.0) * 1.15
        self.scale = min(self.size) / span  # pixels per metre
        self.origin = (width - self.size[0] - 10, height - self.size[1] - 10)

    def _px(self, xz: np.ndarray) -> np.ndarray:
        w, h = self.size
        # Seen from above: x to the right, +z up the map.
        u = self.origin[0] + w / 2 + (xz[..., 0] - self.centre[0]) * self.scale
        v = self.origin[1] + h / 2 - (xz[..., 1] - self.centre[1]) * self.scale
        return np.round(np.stack([u, v], axis=-1) * 4).astype(np.int32)

    def draw(self, image: np.ndarray, t: int, video_intrinsics, video_size) -> None:
        import cv2

        x0, y0 = self.origin
        w, h = self.size
        box = image[y0:y0 + h, x0:x0 + w]
        box[:] = (0.35 * box + 0.65 * 250).astype(np.uint8)
        cv2.rectangle(image, (x0, y0), (x0 + w - 1, y0 + h - 1), (120, 120, 120), 1)
        for track in self.tracks:
            upto = min(t - track.first_frame + 1, track.num_frames)
            if upto < 1:
                continue
            path = track.pelvis[:upto, [0, 2]]
            path = path[np.isfinite(path).all(axis=1)]
            colour = _darker(track_colour(track.track_id), 0.8)
            if len(path) >= 2:
                cv2.polylines(image, [self._px(path).reshape(-1, 1, 2)], False, colour, 1, cv2.LINE_AA, shift=2)
            if len(path):
                cv2.circle(image, tuple(self._px(path[-1])), 3 * 4, colour, -1, cv2.LINE_AA, shift=2)
        cams = self.cameras[:t + 1, [0, 2]]
        cams = cams[np.isfinite(cams).all(axis=1)]
        if len(cams) >= 2:
            cv2.polylines(image, [self._px(cams).reshape(-1, 1, 2)], False, (40, 40, 40), 1, cv2.LINE_AA, shift=2)
        if len(cams):
            self._frustum(image, t, video_intrinsics, video_size)
        # 1 m (or a round length) of the map.
        metres = nice_step(w / self.scale / 2.5)
        length = int(round(metres * self.scale))
        cv2.line(image, (x0 + 6, y0 + h - 8), (x0 + 6 + length, y0 + h - 8), (40, 40, 40), 1, cv2.LINE_AA)
        cv2.putText(image, f"{metres:g} m", (x0 + 10 + length, y0 + h - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (40, 40, 40), 1, cv2.LINE_AA)

    def _frustum(self, image, t, video_intrinsics, video_size) -> None:
        """The video camera at frame t from above: its centre and its horizontal field of view 1.5 m out."""
        import cv2

        pose = self.poses[t]
        if not np.isfinite(pose).all():
            return
        w = video_size[0]
        fx, _, cx, _ = video_intrinsics
        ends = [pose[:3, :3] @ np.array([(u - cx) / fx, 0.0, 1.0]) * 1.5 + pose[:3, 3] for u in (0.0, w)]
        tri = self._px(np.stack([pose[:3, 3], *ends])[:, [0, 2]])
        cv2.polylines(image, [tri.reshape(-1, 1, 2)], True, (30, 30, 200), 1, cv2.LINE_AA, shift=2)


def track_motions(model, tracks: list[dict], contact_threshold: float) -> list[TrackMotion]:
    """TrackMotion of each result track (world joints from the body model, planted feet from its contacts:
    a foot is planted where its ankle or its foot joint has contact probability >= contact_threshold)."""
    from m3c.body.joint_names import CONTACT_JOINTS
    from m3c.ground.tracks import track_poses

    out = []
    for track in tracks:
        joints = model.joints(track_poses(track), np.asarray(track["betas"]), np.asarray(track["transl"]))
        n = len(joints)
        contacts = track.get("contacts")
        contacts = np.zeros((n, 4)) if contacts is None else np.asarray(contacts, dtype=np.float64)[:n]
        index = {j: k for k, j in enumerate(CONTACT_JOINTS)}  # (7, 8, 10, 11): ankles then feet
        planted = np.stack([(contacts[:, index[7]] >= contact_threshold) | (contacts[:, index[10]] >= contact_threshold),
                            (contacts[:, index[8]] >= contact_threshold) | (contacts[:, index[11]] >= contact_threshold)])
        out.append(TrackMotion(int(track["track_id"]), int(track["first_frame"]), joints[:, [1, 2]].mean(axis=1),
                               np.stack([joints[:, 7], joints[:, 8]]), np.stack([joints[:, 10], joints[:, 11]]),
                               planted))
    return out
