"""The pinhole camera in Python, one owner for: a world point in a camera (to_camera), a camera point in the image
(project), both at once (world_to_image), the camera at a point looking at another (look_at), and the pipeline's
cameras in the world with their visual-odometry scale (WorldCameras, from the ground node to the results).

Cameras are OpenCV's: x right, y down, z forward; world_from_cam (4, 4) is rigid (its columns are the camera's axes
in the world, its last column the camera centre); intrinsics are [fx, fy, cx, cy] in pixels, no distortion.
"""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass(frozen=True)
class WorldCameras:
    """The video's T cameras in M3C's world frame (gravity-aligned, y up; m3c.ground.world_frame), as visual odometry
    measured them and a camera scale sizes them: the camera centre of frame t is, in metres,
    ``scale[t] * centre_vo[t] + offset[t]``. world_from_cam() applies that, the one place the scale is applied.

    rotation: (T, 3, 3) world_from_cam rotations (columns: the camera's axes in world axes); the same at any scale.
    centre_vo: (T, 3) camera centres in world axes about the world's origin, in VO units (the odometry's
        translation unit, whose size in metres is unknown until a scale is estimated).
    scale: metres per VO unit, one for the video () or one per frame (T,) (windowed optimization blends its windows'
        scales frame by frame); finite and > 0.
    offset: metres added after scaling, (3,) or per frame (T, 3); 0 for the lift's cameras, the optimizer's
        camera offset (and the shift that sets the ground back at y = 0) for the optimised ones.

    The pipeline's nodes carry it as a dict of its fields (as_dict; WorldCameras(**d) reads it back). The optimizer
    (m3c.motion.optimize.Cameras) takes centre_vo and the scale as its own model: centre = scale * centre_vo +
    offset, the offset starting at 0 (world_from_cam_vo gives its input poses).
    """

    rotation: np.ndarray
    centre_vo: np.ndarray
    scale: np.ndarray | float
    offset: np.ndarray | float = 0.0

    def __post_init__(self):
        rotation = _frozen(self.rotation, "rotation")
        if rotation.ndim != 3 or rotation.shape[1:] != (3, 3):
            raise ValueError(f"WorldCameras.rotation must have shape (T, 3, 3), got {rotation.shape}")
        T = len(rotation)
        centre = _frozen(self.centre_vo, "centre_vo")
        if centre.shape != (T, 3):
            raise ValueError(f"WorldCameras.centre_vo must have shape (T={T}, 3) like rotation, got {centre.shape}")
        scale = _frozen(_checked_scale(self.scale, T), "scale")
        offset = _frozen(np.broadcast_to(self.offset, (3,)) if np.ndim(self.offset) == 0 else self.offset, "offset")
        if offset.shape not in ((3,), (T, 3)):
            raise ValueError(f"WorldCameras.offset (metres) must have shape (3,) or (T={T}, 3), got {offset.shape}")
        for name, value in (("rotation", rotation), ("centre_vo", centre), ("scale", scale), ("offset", offset)):
            object.__setattr__(self, name, value)

    @classmethod
    def from_vo(cls, vo_world_from_cam: np.ndarray, scale, world_from_vo: np.ndarray | None = None,
                offset=0.0) -> WorldCameras:
        """The cameras of visual odometry's poses vo_world_from_cam (T, 4, 4) (VO frame, translations in VO units)
        at `scale` metres per VO unit, in the world that world_from_vo (4, 4) (the metric VO frame at that scale ->
        the world; m3c.ground.world_frame.estimate_ground) defines; None: the VO frame itself."""
        vo = np.asarray(vo_world_from_cam, dtype=np.float64)
        if vo.ndim != 3 or vo.shape[1:] != (4, 4):
            raise ValueError(f"vo_world_from_cam must have shape (T, 4, 4), got {vo.shape}")
        rotation, centre = vo[:, :3, :3], vo[:, :3, 3]
        if world_from_vo is not None:
            frame = np.asarray(world_from_vo, dtype=np.float64)
            if frame.shape != (4, 4) or not np.isfinite(frame).all():
                raise ValueError(f"world_from_vo must be a finite (4, 4) matrix, got shape {frame.shape}")
            scale = _checked_scale(scale, len(vo))
            # The world's origin in VO units: the optimizer scales the cameras about it.
            rotation = frame[:3, :3] @ rotation
            centre = centre @ frame[:3, :3].T + frame[:3, 3] / np.reshape(scale, (-1, 1))
        return cls(rotation, centre, scale, offset)

    def __len__(self) -> int:
        return len(self.rotation)

    def world_from_cam(self) -> np.ndarray:
        """(T, 4, 4) the cameras in the world, metres: rotation and scale * centre_vo + offset."""
        out = np.zeros((len(self), 4, 4))
        out[:, :3, :3] = self.rotation
        out[:, :3, 3] = self.scale[..., None] * self.centre_vo + self.offset
        out[:, 3, 3] = 1.0
        return out

    def world_from_cam_vo(self) -> np.ndarray:
        """(T, 4, 4) rotation and centre_vo: the poses in world axes with their centres in VO units, the scale not
        applied (the optimizer's Cameras.world_from_cam)."""
        out = np.zeros((len(self), 4, 4))
        out[:, :3, :3] = self.rotation
        out[:, :3, 3] = self.centre_vo
        out[:, 3, 3] = 1.0
        return out

    def as_dict(self) -> dict:
        """The fields by name, as the pipeline's nodes hand them on (WorldCameras(**d) reads them back)."""
        return {"rotation": self.rotation, "centre_vo": self.centre_vo, "scale": self.scale, "offset": self.offset}


def _checked_scale(scale, num_frames: int) -> np.ndarray:
    scale = np.asarray(scale, dtype=np.float64)
    if scale.shape not in ((), (num_frames,)):
        raise ValueError(f"the camera scale (metres per VO unit) must be one value or one per frame "
                         f"(T={num_frames},), got shape {scale.shape}")
    if not (np.isfinite(scale).all() and (scale > 0).all()):
        raise ValueError(f"the camera scale (metres per VO unit) must be finite and > 0, got "
                         f"{scale if scale.ndim == 0 else scale[~(np.isfinite(scale) & (scale > 0))][:3]}")
    return scale


def _frozen(value, name: str) -> np.ndarray:
    """A read-only float64 copy of `value`, which must be finite."""
    out = np.array(value, dtype=np.float64, copy=True)
    if not np.isfinite(out).all():
        raise ValueError(f"WorldCameras.{name} must be finite, got {np.count_nonzero(~np.isfinite(out))} "
                         "non-finite value(s)")
    out.flags.writeable = False
    return out
