"""Moving SMPL parameters between coordinate frames.

SMPL rotates the body about its root joint, not about the origin: a vertex is R_root (x - j0) + j0 + transl, with
j0 the rest-pose root joint of the person's shape. Under a rigid map y = R x + c (target_from_source) the same
body in the target frame has R_root' = R R_root and transl' = R (j0 + transl) + c - j0.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body.joint_names import SMPL_JOINT_NAMES


def rest_root_joint(model, betas) -> np.ndarray:
    """The root joint of the rest pose of shape `betas` (no translation), metres: (3,) for betas (B,), (n, 3) for
    (n, B). The root rotation turns about it."""
    betas = np.asarray(betas, dtype=np.float64)
    if betas.ndim == 1:
        return model.joints(np.zeros((1, model.num_joints, 3)), betas)[0, 0]
    return model.joints(np.zeros((len(betas), model.num_joints, 3)), betas)[:, 0]


def transform_smpl(target_from_source, root_orient, transl, root_joint) -> tuple[np.ndarray, np.ndarray]:
    """target_from_source (4, 4) or (n, 4, 4); root_orient (n, 3) axis-angle; transl (n, 3); root_joint (3,) or
    (n, 3), the rest root joint (rest_root_joint). Returns (root_orient (n, 3), transl (n, 3)) of the same bodies
    in the target frame: the body rotates about its root joint J0, so J0 + transl' = R (J0 + transl) + t."""
    root_orient = np.asarray(root_orient, dtype=np.float64).reshape(-1, 3)
    transl = np.asarray(transl, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(target_from_source, dtype=np.float64)
    if T.shape == (4, 4):
        T = np.broadcast_to(T, (len(root_orient), 4, 4))
    if T.shape != (len(root_orient), 4, 4):
        raise ValueError(f"target_from_source must be (4, 4) or ({len(root_orient)}, 4, 4), got {T.shape}")
    R, c = T[:, :3, :3], T[:, :3, 3]
    j0 = np.broadcast_to(np.asarray(root_joint, dtype=np.float64), (len(root_orient), 3))
    new_root = (Rotation.from_matrix(R) * Rotation.from_rotvec(root_orient)).as_rotvec()
    new_transl = np.einsum("nij,nj->ni", R, j0 + transl) + c - j0
    return new_root, new_transl


def spine_directions(joints: np.ndarray) -> np.ndarray:
    """Unit pelvis-to-neck directions (n, 3) of SMPL joints (n, J, 3), in the joints' frame: M3C's one rule for
    reading "up" from bodies (people stand and walk mostly upright), averaged by m3c.perception.contacts.
    estimate_up and, in the odometry's frame, m3c.ground.world_frame.body_up."""
    spine = joints[:, SMPL_JOINT_NAMES.index("neck")] - joints[:, SMPL_JOINT_NAMES.index("pelvis")]
    return spine / np.maximum(np.linalg.norm(spine, axis=1, keepdims=True), 1e-9)


def facing_directions(joints: np.ndarray, up) -> np.ndarray:
    """Unit directions (n, 3) the body faces, horizontal to `up` (3,), of SMPL joints (n, J, 3): perpendicular to
    the right-to-left line of the hips and the shoulders (in the rest pose, y up, the body faces +z with its left
    at +x). Zero where that line is vertical."""
    name = SMPL_JOINT_NAMES.index
    side = (joints[:, name("left_hip")] - joints[:, name("right_hip")] +
            joints[:, name("left_shoulder")] - joints[:, name("right_shoulder")])
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    forward = np.cross(side, up)  # perpendicular to up: horizontal
    norm = np.linalg.norm(forward, axis=1, keepdims=True)
    return np.where(norm > 1e-9, forward / np.maximum(norm, 1e-9), 0.0)
