"""Synthetic hand images with ground truth: the open body model with posed fingers (m3c.body.hands), rendered
close up by the numpy rasteriser (m3c.viz.raster) in skin colour over grey, with the body's COCO-17 keypoints
(projected joints) standing in for the body detector. Used by the hand tests and bench/hands_synthetic.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.body.hands import SIDES, load_hand_model, pose_hands, skin_hands, wrist_frames
from m3c.body.joint_names import COCO17_NAMES, SMPL_JOINT_NAMES
from m3c.camera import look_at, project, to_camera
from m3c.perception.hand_fit import dofs_to_pose, hand_axes

SKIN = np.array([0.87, 0.68, 0.58])
# The left arm out to the side, a little down, the forearm bent forwards; the right arm down.
ARM_POSE = {"left_shoulder": (0.0, 0.0, -0.35), "right_shoulder": (0.0, 0.0, 1.2),
            "left_elbow": (0.0, -0.9, 0.0), "left_wrist": (0.0, 0.0, 0.0)}


@dataclass
class HandScene:
    """image (H x W x 3 BGR), keypoints (17 x 3 COCO-17 u, v, confidence of the body), hand_keypoints_in_world
    (2 x 21 x 3, MediaPipe order), hand_pixels (2 x 21 x 2), wrist_rotation (2 x 3 x 3), wrist_position (2 x
    3), world_from_cam (4 x 4), intrinsics (4,), hand_pose (2 x 15 x 3)."""

    image: np.ndarray
    keypoints: np.ndarray
    hand_keypoints_in_world: np.ndarray
    hand_pixels: np.ndarray
    wrist_rotation: np.ndarray
    wrist_position: np.ndarray
    world_from_cam: np.ndarray
    intrinsics: np.ndarray
    hand_pose: np.ndarray


def body_pose(wrist_turn=(0.0, 0.0, 0.0)) -> np.ndarray:
    pose = np.zeros((1, 24, 3))
    for name, value in ARM_POSE.items():
        pose[0, SMPL_JOINT_NAMES.index(name)] = value
    pose[0, SMPL_JOINT_NAMES.index("left_wrist")] += np.asarray(wrist_turn)
    return pose


def render_hand_scene(model, dofs: np.ndarray, distance: float = 0.8, view=(0.2, -1.0, 0.6), betas=None,
                      width: int = 640, height: int = 480, focal: float = 900.0, wrist_turn=(0.0, 0.0, 0.0),
                      hand=None) -> HandScene:
    """The left hand posed by dofs (m3c.perception.hand_fit.DOFS; the right hand at rest), seen from
    `distance` metres along `view` (world direction from the left wrist), the camera looking at the left
    palm's centre."""
    from m3c.viz.raster import Mesh, render

    hand = load_hand_model() if hand is None else hand
    betas = np.zeros(model.num_betas) if betas is None else np.asarray(betas, dtype=np.float64)
    pose = body_pose(wrist_turn)
    rotation, position = wrist_frames(model, pose, betas)
    axes = hand_axes(hand, betas)
    hand_pose = np.zeros((1, 2, 15, 3))
    hand_pose[0, 0] = dofs_to_pose(np.asarray(dofs, dtype=np.float64), axes[0])
    posed = pose_hands(hand, betas, rotation, position, hand_pose)
    keys = posed.keypoints()[0]
    rest = model.data.v_template + model.data.shapedirs @ betas
    body = model.forward(pose, betas).vertices
    vertices = skin_hands(hand, betas, rest, body, rotation, position, hand_pose)[0]
    target = keys[0, 0] + 0.5 * (keys[0, 9] - keys[0, 0])
    view = np.asarray(view, dtype=np.float64)
    world_from_cam = look_at(target + distance * view / np.linalg.norm(view), target)
    K = np.array([focal, focal, width / 2 - 0.5, height / 2 - 0.5])
    image, _ = render([Mesh(to_camera(vertices, world_from_cam), model.faces, SKIN)], K, width, height,
                      background=np.full((height, width, 3), 90, np.uint8))
    joints = model.joints(pose, betas)[0]
    coco = np.zeros((17, 3))
    for k, name in enumerate(COCO17_NAMES):
        if name in SMPL_JOINT_NAMES:
            coco[k, :2] = project(to_camera(joints[SMPL_JOINT_NAMES.index(name)], world_from_cam), K)
            coco[k, 2] = 0.9
    return HandScene(image, coco, keys, project(to_camera(keys, world_from_cam), K), rotation[0], position[0],
                     world_from_cam, K, hand_pose[0])


def side_index(side: str) -> int:
    return SIDES.index(side)
