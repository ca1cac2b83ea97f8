"""The pinhole camera in Python, one owner for: a world point in a camera (to_camera), a camera point in the image
(project), both at once (world_to_image), and the camera at a point looking at another (look_at).

Cameras are OpenCV's: x right, y down, z forward; world_from_cam (4, 4) is rigid (its columns are the camera's axes
in the world, its last column the camera centre); intrinsics are [fx, fy, cx, cy] in pixels, no distortion.
"""

from __future__ import annotations

import numpy as np

UP = np.array([0.0, 1.0, 0.0])  # M3C's world up (y)


def to_camera(points_in_world: np.ndarray, world_from_cam: np.ndarray) -> np.ndarray:
    """World points in camera coordinates. world_from_cam (4, 4): one camera, points (..., 3); (n, 4, 4): camera i
    for points[i], points (n, K, 3)."""
    pose = np.asarray(world_from_cam)
    R, c = pose[..., :3, :3], pose[..., :3, 3]
    if pose.ndim == 2:
        return (points_in_world - c) @ R
    return np.einsum("nji,nkj->nki", R, points_in_world - c[:, None])


def project(points_in_cam: np.ndarray, intrinsics) -> np.ndarray:
    """Camera points (..., 3) -> pixels (..., 2). intrinsics [fx, fy, cx, cy] (4,), or an array (..., 4) that
    broadcasts against the points' leading axes (per camera: (n, 1, 4) for points (n, K, 3)). Points at z = 0 give
    inf or NaN (no warning); points behind the camera project through the centre, as the formula does."""
    k = np.asarray(intrinsics, dtype=np.float64)
    fx, fy, cx, cy = k[..., 0], k[..., 1], k[..., 2], k[..., 3]
    x, y, z = points_in_cam[..., 0], points_in_cam[..., 1], points_in_cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([fx * x / z + cx, fy * y / z + cy], axis=-1)


def world_to_image(points_in_world: np.ndarray, world_from_cam: np.ndarray, intrinsics) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """World points (..., 3) seen by one camera: (pixels (..., 2), depth along the optical axis (...))."""
    cam = to_camera(points_in_world, world_from_cam)
    return project(cam, intrinsics), cam[..., 2]


def look_at(eye: np.ndarray, target: np.ndarray, up=UP) -> np.ndarray:
    """world_from_cam (4, 4) of an OpenCV camera at `eye` looking at `target`, image y pointing against `up`."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))  # z x up points to the camera's right
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = eye
    return pose
