"""A synthetic SMPL-layout body model for tests and benchmarks: random but structured like SMPL (human joint
layout, vertices along the bones, sparse skinning weights, a sparse joint regressor whose rows sum to 1).
It lets every test run without the licensed SMPL files."""

from __future__ import annotations

import numpy as np

from m3c.body.joint_names import SMPL_PARENTS
from m3c.body.model_file import BodyModelData

# Approximate rest joints of a 1.7 m person (metres, y up, facing +z, pelvis at the origin).
REST_JOINTS = np.array([
    [0.0, 0.0, 0.0], [0.06, -0.09, 0.0], [-0.06, -0.09, 0.0], [0.0, 0.11, -0.02], [0.1, -0.47, 0.0],
    [-0.1, -0.47, 0.0], [0.0, 0.25, 0.0], [0.08, -0.87, -0.04], [-0.08, -0.87, -0.04], [0.0, 0.31, 0.02],
    [0.11, -0.93, 0.08], [-0.11, -0.93, 0.08], [0.0, 0.52, -0.01], [0.07, 0.43, 0.0], [-0.07, 0.43, 0.0],
    [0.0, 0.6, 0.04], [0.18, 0.45, -0.01], [-0.18, 0.45, -0.01], [0.44, 0.43, -0.03], [-0.44, 0.43, -0.03],
    [0.7, 0.44, -0.01], [-0.7, 0.44, -0.01], [0.79, 0.43, -0.02], [-0.79, 0.43, -0.02],
])


def make_synthetic_model(vertices_per_bone: int = 24, num_betas: int = 10, seed: int = 0,
                         posedirs_scale: float = 2e-3, num_vertices: int | None = None) -> BodyModelData:
    """vertices_per_bone vertices along each of the 23 bones plus as many on the head; num_vertices, when given,
    sets the total instead (6890 for a SMPL-sized model)."""
    rng = np.random.default_rng(seed)
    head_vertices = vertices_per_bone
    if num_vertices is not None:
        vertices_per_bone = num_vertices // 24
        head_vertices = num_vertices - 23 * vertices_per_bone
    parents = np.asarray(SMPL_PARENTS)
    J = len(parents)
    verts, weights = [], []
    for j in range(1, J):
        p = parents[j]
        t = rng.uniform(0.0, 1.0, vertices_per_bone)
        axis = REST_JOINTS[j] - REST_JOINTS[p]
        offsets = rng.normal(size=(vertices_per_bone, 3))
        offsets -= np.outer(offsets @ axis, axis) / max(axis @ axis, 1e-9)
        offsets *= 0.05 / np.linalg.norm(offsets, axis=1, keepdims=True)
        verts.append(REST_JOINTS[p] + np.outer(t, axis) + offsets)
        w = np.zeros((vertices_per_bone, J))
        # Sparse blend: the parent near its end, both in the middle, the child near its end.
        w[:, p] = np.clip(1.5 - 2.0 * t, 0.0, 1.0)
        w[:, j] = 1.0 - w[:, p]
        weights.append(w)
    head = REST_JOINTS[15] + 0.1 * rng.normal(size=(head_vertices, 3)) / np.sqrt(3)
    verts.append(head)
    w = np.zeros((head_vertices, J))
    w[:, 15] = 1.0
    weights.append(w)
    v_template = np.concatenate(verts)
    weights = np.concatenate(weights)
    V = len(v_template)

    # Each joint is a convex combination of its 8 nearest vertices (rows sum to 1).
    J_regressor = np.zeros((J, V))
    for j in range(J):
        nearest = np.argsort(np.linalg.norm(v_template - REST_JOINTS[j], axis=1))[:8]
        w = rng.uniform(0.5, 1.5, len(nearest))
        J_regressor[j, nearest] = w / w.sum()

    # Shape: component 0 is height, the rest smooth random fields.
    shapedirs = np.zeros((V, 3, num_betas))
    if num_betas:
        shapedirs[:, 1, 0] = 0.06 * v_template[:, 1]
    for b in range(1, num_betas):
        freq = rng.normal(size=(3, 3)) * 3.0
        amp = rng.uniform(0.005, 0.02, size=3)
        shapedirs[:, :, b] = amp * np.sin(v_template @ freq + rng.uniform(0, np.pi, 3))
    posedirs = posedirs_scale * rng.normal(size=(V, 3, 9 * (J - 1)))

    faces = []
    for start in range(0, V - 2, 3):
        faces.append([start, start + 1, start + 2])
    # Keypoint vertices: the head vertex nearest to where a face point would be, the foot vertex nearest to toe
    # and heel, the hand vertex at the hand joint.
    spots = {"nose": (15, [0.0, 0.0, 0.1]), "left_eye": (15, [0.03, 0.03, 0.08]),
             "right_eye": (15, [-0.03, 0.03, 0.08]), "left_ear": (15, [0.08, 0.0, 0.0]),
             "right_ear": (15, [-0.08, 0.0, 0.0]), "left_big_toe": (10, [0.0, -0.03, 0.08]),
             "left_small_toe": (10, [0.04, -0.03, 0.06]), "left_heel": (7, [0.0, -0.06, -0.05]),
             "right_big_toe": (11, [0.0, -0.03, 0.08]), "right_small_toe": (11, [-0.04, -0.03, 0.06]),
             "right_heel": (8, [0.0, -0.06, -0.05]), "left_hand": (22, [0.0, 0.0, 0.0]),
             "right_hand": (23, [0.0, 0.0, 0.0])}
    keypoint_ids = {name: int(np.argmin(np.linalg.norm(v_template - (REST_JOINTS[j] + off), axis=1)))
                    for name, (j, off) in spots.items()}
    return BodyModelData(v_template, shapedirs, posedirs, J_regressor, weights, parents.astype(np.int64),
                         np.asarray(faces, dtype=np.int32), name="synthetic", keypoint_vertex_ids=keypoint_ids)


def random_pose(num_frames: int, num_joints: int = 24, scale: float = 0.4, seed: int = 0) -> np.ndarray:
    """N x J x 3 axis-angle poses with a free root rotation and moderate joint angles."""
    rng = np.random.default_rng(seed)
    pose = scale * rng.normal(size=(num_frames, num_joints, 3))
    pose[:, 0] = rng.normal(size=(num_frames, 3))
    return pose
