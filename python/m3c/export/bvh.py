"""BVH export: one file per person, SMPL's 24-joint hierarchy at the person's own shape.

The rest pose is the body model's T pose at the track's betas: each OFFSET is a joint's rest position minus
its parent's. The root's position channels hold the root joint's world position per frame (rest root + SMPL
translation: SMPL rotates the body about that joint), the rotation channels each joint's rotation relative to
its parent (Z, Y, X Euler angles in degrees, R = Rz Ry Rx). Where the results hold hand poses (the open
model's hands), 30 SMPL-H finger joints follow, hanging off the wrists, with the fingertips as end sites. Axes
are the results' world (y up, metres, +z the first camera's viewing direction); the unit is centimetres by
default (unit="m" for metres).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.export.source import ExportSource, TrackMotion, finger_skeleton, per_track_paths
from m3c.io.bvh import BVHJoint, BVHMotion, write_bvh

UNITS = {"cm": 100.0, "m": 1.0}
_ROTATION_CHANNELS = ["Zrotation", "Yrotation", "Xrotation"]
_END_SITE_FRACTION = 0.5  # end sites continue a leaf joint's bone by half its length (a bone tail for importers)


def euler_zyx_degrees(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle -> (..., 3) Z, Y, X angles in degrees (R = Rz Ry Rx), unwrapped along the first axis
    so that consecutive frames never jump by 360 degrees (the same rotations, smoother to interpolate)."""
    shape = rotvec.shape
    with warnings.catch_warnings():
        # At Y = +-90 degrees Z and X are not unique; scipy picks one exact solution and warns.
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        angles = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_euler("ZYX", degrees=True).reshape(shape)
    return np.unwrap(angles, period=360.0, axis=0) if len(angles) > 1 else angles


def track_bvh(source: ExportSource, track: TrackMotion, unit: str = "cm") -> BVHMotion:
    """The track's motion as a BVHMotion (joints in SMPL order, end sites after them)."""
    if unit not in UNITS:
        raise ValueError(f"BVH unit must be one of {sorted(UNITS)}, got {unit!r}")
    scale = UNITS[unit]
    parents = source.parents
    names = source.joint_names
    rest = track.rest_joints * scale
    euler = euler_zyx_degrees(track.pose)                                   # (n, 24, 3)
    columns = [track.root_positions * scale, euler[:, 0]]
    joints = [BVHJoint(names[0], -1, rest[0], ["Xposition", "Yposition", "Zposition"] + _ROTATION_CHANNELS, 0)]
    start = 6
    for j in range(1, len(parents)):
        joints.append(BVHJoint(names[j], int(parents[j]), rest[j] - rest[parents[j]], list(_ROTATION_CHANNELS),
                               start))
        columns.append(euler[:, j])
        start += 3
    fingers = finger_skeleton(track)
    if fingers is not None:  # 30 finger joints below the wrists, their tips as end sites
        all_rest = np.concatenate([rest, fingers.rest * scale])
        finger_euler = euler_zyx_degrees(fingers.pose)
        for k, (name, parent) in enumerate(zip(fingers.names, fingers.parents)):
            joints.append(BVHJoint(name, int(parent), all_rest[24 + k] - all_rest[parent],
                                   list(_ROTATION_CHANNELS), start))
            columns.append(finger_euler[:, k])
            start += 3
        for k, parent in enumerate(fingers.tip_parents):
            joints.append(BVHJoint(f"{fingers.names[parent - 24]}_end", int(parent),
                                   fingers.tips[k] * scale - all_rest[parent], [], start, end_site=True))
    for j in range(len(parents)):
        if j not in parents:  # a leaf: head, hands, feet
            joints.append(BVHJoint(f"{names[j]}_end", j, _END_SITE_FRACTION * (rest[j] - rest[parents[j]]), [],
                                   start, end_site=True))
    return BVHMotion(joints, 1.0 / source.fps, np.concatenate(columns, axis=1))


def export_bvh(source: ExportSource, out: Path, unit: str = "cm") -> list[Path]:
    """One BVH per selected track: out/<stem>_track<ID>.bvh when out is a folder (or has no .bvh suffix),
    out itself when exactly one track is exported and out ends in .bvh."""
    paths = per_track_paths(source, out, ".bvh", "motion")
    for track, path in zip(source.tracks, paths):
        write_bvh(path, track_bvh(source, track, unit))
    return paths

