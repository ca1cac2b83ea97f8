"""What the metrics compare: one person's body over frames, in the camera frame and in the world frame.

An EvalTrack is built from body-model parameters (thesis 5.2.4, fair comparison: predictions and ground truth
are both posed by the body model from their final parameters, never from meshes cached elsewhere).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.body import BodyModel
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.eval.matching import JointTrack

# Foot points for foot sliding, by keypoint-vertex name (GVHMR uses SMPL vertices 3216, 3387, 6617, 6787: the
# big
# toes and heels, which these names select on SMPL).
FOOT_VERTEX_NAMES = ("left_big_toe", "left_heel", "right_big_toe", "right_heel")


@dataclass
class EvalTrack:
    """One person over frame ids `frames` (n,), metres. joints_* use the evaluation joints (n, J, 3)."""

    frames: np.ndarray
    joints_cam: np.ndarray
    vertices_cam: np.ndarray | None = None
    joints_world: np.ndarray | None = None
    feet_world: np.ndarray | None = None     # (n, 4, 3) foot points for foot sliding

    def joint_track(self) -> JointTrack:
        return JointTrack(self.frames, self.joints_cam)

    def take(self, index) -> "EvalTrack":
        pick = (lambda a: None if a is None else a[index])
        return EvalTrack(self.frames[index], self.joints_cam[index], pick(self.vertices_cam),
                         pick(self.joints_world), pick(self.feet_world))


def foot_vertex_ids(model: BodyModel) -> list[int]:
    table = model.keypoint_vertex_ids()
    return [int(table[name]) for name in FOOT_VERTEX_NAMES]


def body_eval_track(model: BodyModel, frames, root_orient, body_pose, betas, transl, world_from_cam,
                    eval_regressor=None, with_vertices: bool = True) -> EvalTrack:
    """Poses the body in the world (root_orient, transl world frame) and in each frame's camera
    (world_from_cam (n, 4, 4) for these frames) and evaluates it.

    eval_regressor: a keypoint regressor for the evaluation joints (e.g. BodyModel.h36m_regressor(...,
    evaluation_joints=True) for the 14 joints); None uses the model's 24 joints.
    """
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    n = len(frames)
    root_orient = np.asarray(root_orient, dtype=np.float64).reshape(n, 3)
    body_pose = np.asarray(body_pose, dtype=np.float64).reshape(n, -1, 3)
    transl = np.asarray(transl, dtype=np.float64).reshape(n, 3)
    betas = np.asarray(betas, dtype=np.float64)
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    if world_from_cam.shape != (n, 4, 4):
        raise ValueError(f"world_from_cam must have shape ({n}, 4, 4) for the track's frames, got "
                         f"{world_from_cam.shape}")
    cam_from_world = np.linalg.inv(world_from_cam)
    j0 = rest_root_joint(model, betas)
    root_cam, transl_cam = transform_smpl(cam_from_world, root_orient, transl, j0)

    def evaluate(root, tr):
        pose = np.concatenate([root[:, None], body_pose], axis=1)
        if with_vertices:
            out = model.forward(pose, betas, tr)
            verts = out.vertices
            joints = out.joints if eval_regressor is None else model.keypoints(eval_regressor, pose, betas, tr)
            return joints, verts
        joints = model.joints(pose, betas, tr) if eval_regressor is None else \
            model.keypoints(eval_regressor, pose, betas, tr)
        return joints, None

    joints_cam, vertices_cam = evaluate(root_cam, transl_cam)
    joints_world, vertices_world = evaluate(root_orient, transl)
    feet = None
    if vertices_world is not None:
        try:
            feet = vertices_world[:, foot_vertex_ids(model)]
        except ValueError:
            feet = None  # a model without a keypoint-vertex table: no foot sliding
    return EvalTrack(frames, joints_cam, vertices_cam, joints_world, feet)
