"""Metric scale of monocular visual odometry from the ground.

The people's contact points give the ground plane in metric camera coordinates (unit normal n pointing up,
towards the camera's side, and the camera's height h above it in metres). The VO map has points on the same
ground in VO units: seen from the same camera, their height below it along -n is h / scale. Each VO point
below the camera, near the ground's direction, is a vote log(h_t / height) for log(scale); the ground is the
densest narrow peak among the votes (trees, walls, cars and people give spread-out votes of their own).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GroundScaleInfo:
    """What scale_from_ground saw.

    support: votes in the ground peak (point-frame pairs); points: distinct map points among them;
    frames: frames that contributed to the peak; candidates: votes in the cone below the camera;
    spread: robust standard deviation (1.4826 MAD) of the peak's log-votes, i.e. relative scale spread;
    contrast: peak votes over the votes of the denser of the two equally wide bands beside it;
    reason: why no scale was returned ("" when one was).
    """
    support: int = 0
    points: int = 0
    frames: int = 0
    candidates: int = 0
    spread: float = float("nan")
    contrast: float = 0.0
    reason: str = ""


def _densest_window(values: np.ndarray, half_width: float) -> float:
    """Centre of the interval of width 2 * half_width holding the most of the sorted `values`."""
    right = np.searchsorted(values, values + 2.0 * half_width, side="right")
    best = int(np.argmax(right - np.arange(len(values))))
    return float(np.median(values[best:right[best]]))


def scale_from_ground(points: np.ndarray, world_from_cam: np.ndarray, ground_normal_cam: np.ndarray,
                      camera_height_m: np.ndarray, frames: np.ndarray | None = None, *,
                      max_angle_deg: float = 80.0, min_depth: float = 0.0, half_width: float = 0.05,
                      min_support: int = 20, min_contrast: float = 2.0
                      ) -> tuple[float | None, GroundScaleInfo]:
    """Metres per VO unit from VO map points on the ground.

    Args:
        points: (M, 3) VO map points in the VO world frame (VOResult.points).
        world_from_cam: (T, 4, 4) VO camera poses (VOResult.world_from_cam), translation in VO units.
        ground_normal_cam: (F, 3) for each frame in `frames` the ground's normal in that frame's camera
            coordinates (OpenCV axes), pointing up, i.e. towards the camera's side of the plane; normalised
            here.
        camera_height_m: (F,) the camera's height above that plane, metres (> 0).
        frames: (F,) indices into world_from_cam; None means every frame (F = T).
        max_angle_deg: a point votes in frame t when the angle between its direction from the camera and the
            down direction -n is below this (the ground's part of the view; farther points are grazing and
            mostly not ground).
        min_depth: points must lie at camera z > min_depth (VO units), i.e. in front of the camera.
        half_width: half width of the ground peak in log-scale (0.05: votes within about +-5%).
        min_support: fewest votes in the peak for a scale.
        min_contrast: the peak must hold at least this many times the votes of each equally wide band beside
            it; a smooth spread of heights, or its edge (no surface at one height), fails.

    Returns:
        (scale in metres per VO unit, or None with info.reason; GroundScaleInfo).
    """
    points = np.asarray(points, dtype=np.float64)
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (M, 3), got {points.shape}")
    if world_from_cam.ndim != 3 or world_from_cam.shape[1:] != (4, 4):
        raise ValueError(f"world_from_cam must have shape (T, 4, 4), got {world_from_cam.shape}")
    frames = np.arange(len(world_from_cam)) if frames is None else np.asarray(frames, dtype=np.int64)
    normals = np.asarray(ground_normal_cam, dtype=np.float64)
    heights = np.asarray(camera_height_m, dtype=np.float64)
    if frames.ndim != 1 or normals.shape != (len(frames), 3) or heights.shape != (len(frames),):
        raise ValueError(f"ground_normal_cam must be (F, 3) and camera_height_m (F,) with F = {len(frames)} "
                         f"frames, got {normals.shape} and {heights.shape}")
    if len(frames) and (frames.min() < 0 or frames.max() >= len(world_from_cam)):
        raise ValueError(f"frames must index world_from_cam (0 .. {len(world_from_cam) - 1})")
    norms = np.linalg.norm(normals, axis=1)
    usable = np.isfinite(heights) & (heights > 0) & np.all(np.isfinite(normals), axis=1) & (norms > 1e-9)
    frames, normals, heights = frames[usable], normals[usable] / norms[usable, None], heights[usable]
    info = GroundScaleInfo()
    if len(points) == 0 or len(frames) == 0:
        info.reason = "no map points" if len(points) == 0 else "no frame with a ground plane"
        return None, info

    cos_max = np.cos(np.radians(max_angle_deg))
    votes, vote_point, vote_frame = [], [], []
    for frame, normal, height in zip(frames, normals, heights):
        cam_from_world = np.linalg.inv(world_from_cam[frame])
        x = points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        below = -(x @ normal)  # height of the camera above the point along the ground normal, VO units
        distance = np.linalg.norm(x, axis=1)
        keep = (x[:, 2] > min_depth) & (below > cos_max * distance) & (below > 0)
        votes.append(np.log(height / below[keep]))
        vote_point.append(np.flatnonzero(keep))
        vote_frame.append(np.full(int(keep.sum()), frame))
    votes = np.concatenate(votes)
    vote_point, vote_frame = np.concatenate(vote_point), np.concatenate(vote_frame)
    info.candidates = len(votes)
    if len(votes) < min_support:
        info.reason = f"{len(votes)} map point votes below the camera, fewer than min_support = {min_support}"
        return None, info

    order = np.argsort(votes)
    votes, vote_point, vote_frame = votes[order], vote_point[order], vote_frame[order]
    centre = _densest_window(votes, half_width)
    for _ in range(3):  # re-centre on the peak's median
        centre = float(np.median(votes[np.abs(votes - centre) <= half_width]))
    peak = np.abs(votes - centre) <= half_width
    # Flanks as wide as the peak on either side; the denser one counts, so that the edge of a spread of heights
    # (e.g. the lower end of a wall) is no peak.
    lower = np.count_nonzero((votes < centre - half_width) & (votes >= centre - 3.0 * half_width))
    upper = np.count_nonzero((votes > centre + half_width) & (votes <= centre + 3.0 * half_width))
    info.support = int(peak.sum())
    info.points = len(np.unique(vote_point[peak]))
    info.frames = len(np.unique(vote_frame[peak]))
    info.contrast = float(info.support / max(lower, upper, 1))
    info.spread = float(1.4826 * np.median(np.abs(votes[peak] - centre)))
    if info.support < min_support:
        info.reason = f"the ground peak has {info.support} votes, fewer than min_support = {min_support}"
        return None, info
    if info.contrast < min_contrast:
        info.reason = (f"no surface at one height below the camera: the peak holds {info.contrast:.2f}x the "
                       f"votes of its flanks, less than min_contrast = {min_contrast}")
        return None, info
    return float(np.exp(centre)), info


def ground_in_camera(contact_points_cam: list[np.ndarray], normal_cam: np.ndarray, min_points: int = 1
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame camera height above the ground from contact points in camera coordinates (metres).

    contact_points_cam: per frame an (k, 3) array of ground contact points (camera coordinates, metres);
    normal_cam: (T, 3) the ground's up normal in each frame's camera. The plane through the contacts with that
    normal lies at height median(-n . p) below the camera. Returns (frames with >= min_points contacts,
    their heights); feed normal_cam[frames], heights to scale_from_ground.
    """
    normal_cam = np.asarray(normal_cam, dtype=np.float64)
    if normal_cam.shape != (len(contact_points_cam), 3):
        raise ValueError(f"normal_cam must have shape ({len(contact_points_cam)}, 3), got {normal_cam.shape}")
    frames, heights = [], []
    for t, pts in enumerate(contact_points_cam):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if len(pts) < min_points:
            continue
        n = normal_cam[t] / np.linalg.norm(normal_cam[t])
        frames.append(t)
        heights.append(float(np.median(-(pts @ n))))
    return np.asarray(frames, dtype=np.int64), np.asarray(heights)
