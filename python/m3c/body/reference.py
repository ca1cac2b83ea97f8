"""Independent numpy reference of SMPL linear blend skinning, written from the math (REFERENCE.md F), for
tests. Rotations come from the matrix exponential of the skew matrix (scipy.linalg.expm), not Rodrigues'
formula, so the C++ core and this reference share no rotation code."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from m3c.body.model_file import BodyModelData


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation(axis_angle: np.ndarray) -> np.ndarray:
    return expm(skew(np.asarray(axis_angle, dtype=np.float64)))


def lbs_frame(data: BodyModelData, pose: np.ndarray, betas: np.ndarray, transl: np.ndarray | None = None):
    """One frame. pose: J x 3 axis-angle; betas: B; transl: 3. Returns (vertices V x 3, joints J x 3)."""
    J = data.num_joints
    pose = np.asarray(pose, dtype=np.float64).reshape(J, 3)
    transl = np.zeros(3) if transl is None else np.asarray(transl, dtype=np.float64)
    v_shaped = data.v_template + np.einsum("vcb,b->vc", data.shapedirs, betas)
    rest_joints = data.J_regressor @ v_shaped
    rotations = np.stack([rotation(p) for p in pose])
    feature = (rotations[1:] - np.eye(3)).reshape(-1)
    v_posed = v_shaped + np.einsum("vck,k->vc", data.posedirs, feature)
    world = np.zeros((J, 4, 4))
    for j in range(J):
        local = np.eye(4)
        local[:3, :3] = rotations[j]
        parent = data.parents[j]
        local[:3, 3] = rest_joints[j] - (rest_joints[parent] if parent >= 0 else 0.0)
        world[j] = local if parent < 0 else world[parent] @ local
    skinning = world.copy()
    skinning[:, :3, 3] -= np.einsum("jab,jb->ja", world[:, :3, :3], rest_joints)
    blended = np.einsum("vj,jab->vab", data.weights, skinning)
    vertices = np.einsum("vab,vb->va", blended[:, :3, :3], v_posed) + blended[:, :3, 3]
    return vertices + transl, world[:, :3, 3] + transl


def lbs(data: BodyModelData, pose: np.ndarray, betas: np.ndarray, transl: np.ndarray | None = None):
    """Batched: pose N x J x 3, betas B or N x B, transl None, 3 or N x 3."""
    pose = np.asarray(pose, dtype=np.float64).reshape(len(pose), data.num_joints, 3)
    n = len(pose)
    betas = np.broadcast_to(np.asarray(betas, dtype=np.float64), (n, data.num_betas))
    transl = np.zeros((n, 3)) if transl is None else np.broadcast_to(np.asarray(transl, dtype=np.float64), (n, 3))
    out = [lbs_frame(data, pose[i], betas[i], transl[i]) for i in range(n)]
    return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])
