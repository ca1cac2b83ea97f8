"""Seeded synthetic multi-person scenes with ground truth, for tests and benchmarks of the world-frame stages.

World frame: y up, ground plane y = 0 (normal (0, 1, 0), offset 0). Cameras follow OpenCV (x right, y down,
z forward). People walk procedurally (legs and arms swing at a walking cadence); a handheld camera walks
behind them, looking at the group. The simulated inputs are what the perception and VO stages would give:
VO cameras whose translations are divided by an unknown scale, noisy 2D keypoints with confidences, dropped
detections and occlusion gaps, and an initial world lift from camera-local estimates with depth, orientation,
pose and shape errors, placed with the unscaled VO cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.joint_names import CONTACT_JOINTS
from m3c.camera import UP, look_at, world_to_image
from m3c.motion import Cameras, Track, track_joints
from m3c.perception.contacts import contact_rest_heights

def walking_pose(phase: np.ndarray, num_joints: int = 24) -> np.ndarray:
    """Body pose (n, J-1, 3) of a walking cycle at the given phases (radians)."""
    body = np.zeros((len(phase), num_joints - 1, 3))
    s, c = np.sin(phase), np.cos(phase)
    body[:, 0, 0] = 0.45 * s        # left hip (joint 1) swings about x
    body[:, 1, 0] = -0.45 * s       # right hip
    body[:, 3, 0] = 1.0 * np.clip(-c, 0, None)   # left knee (joint 4) bends during the forward swing
    body[:, 4, 0] = 1.0 * np.clip(c, 0, None)    # right knee
    body[:, 15, 2] = -1.2            # left shoulder (16): arms down from the T-pose
    body[:, 16, 2] = 1.2             # right shoulder (17)
    body[:, 15, 0] = -0.3 * s        # arms swing opposite to the legs
    body[:, 16, 0] = 0.3 * s
    body[:, 17, 1] = -0.3            # elbows (18, 19) slightly bent
    body[:, 18, 1] = 0.3
    return body


@dataclass
class SyntheticScene:
    fps: float
    truth: list[Track]          # ground-truth world tracks
    init: list[Track]           # what the optimizer starts from (keypoints observed, lift with errors,
                                # ground planes in camera coordinates)
    cameras_true: Cameras       # true world_from_cam
    cameras_vo: Cameras         # VO: true rotations, translations divided by vo_scale
    vo_scale: float             # true_translation = vo_scale * vo_translation
    image_size: tuple[int, int]


def make_scene(model: BodyModel, num_people: int = 2, num_frames: int = 60, fps: float = 30.0, seed: int = 0,
               vo_scale: float = 2.0, keypoint_noise_px: float = 2.0, drop_rate: float = 0.1,
               depth_error: float = 0.15, rotation_error: float = 0.1, pose_error: float = 0.08) -> SyntheticScene:
    rng = np.random.default_rng(seed)
    W, H = 960, 540
    f = float(np.hypot(W, H))
    intrinsics = np.array([f, f, W / 2, H / 2])
    regressor = model.coco17_regressor()
    t = np.arange(num_frames) / fps

    truth = []
    for p in range(num_people):
        heading = rng.uniform(-0.3, 0.3)  # walking roughly along +z, away from the camera
        start = np.array([1.2 * (p - (num_people - 1) / 2), 0.0, 4.0 + rng.uniform(0, 1.0)])
        root = np.tile(Rotation.from_rotvec(heading * UP).as_rotvec(), (num_frames, 1))
        cadence = rng.uniform(0.8, 1.0)  # strides per second
        body = walking_pose(2 * np.pi * cadence * t + rng.uniform(0, 2 * np.pi), model.num_joints)
        betas = 0.5 * rng.normal(size=model.num_betas)
        transl, contacts = _planted_root_path(model, root, body, betas, start)
        truth.append(Track(0, np.zeros((num_frames, 17, 3)), transl, root, body, betas,
                           ground_normal=np.tile(UP, (num_frames, 1)), ground_offset=np.zeros(num_frames),
                           contacts=contacts))

    # Handheld camera walking behind the group, looking at its centre, with shake.
    centre_path = np.mean([tr.transl for tr in truth], axis=0)
    world_from_cam = []
    for i in range(num_frames):
        cam_centre = centre_path[i] + np.array([0.4 * np.sin(0.7 * t[i]), 1.6, -4.0])
        cam_centre += 0.01 * rng.normal(size=3)
        target = centre_path[i] + np.array([0.0, 0.9, 0.0]) + 0.02 * rng.normal(size=3)
        world_from_cam.append(look_at(cam_centre, target))
    world_from_cam = np.stack(world_from_cam)
    cameras_true = Cameras(world_from_cam, intrinsics)
    vo = world_from_cam.copy()
    vo[:, :3, 3] /= vo_scale
    cameras_vo = Cameras(vo, intrinsics)

    init = []
    for tr in truth:
        n = tr.num_frames
        pose = np.concatenate([tr.root_orient[:, None], tr.body_pose], axis=1)
        kp3d = model.keypoints(regressor, pose, tr.betas, tr.transl)
        keypoints = np.zeros((n, 17, 3))
        for i in range(n):
            uv, _ = world_to_image(kp3d[i], world_from_cam[i], intrinsics)
            keypoints[i, :, :2] = uv + keypoint_noise_px * rng.normal(size=(17, 2))
            keypoints[i, :, 2] = rng.uniform(0.6, 1.0, size=17)
        keypoints[rng.uniform(size=n) < drop_rate] = 0.0  # missed detections
        gap = rng.integers(n // 3, 2 * n // 3)
        keypoints[gap:gap + 5] = 0.0  # a short occlusion
        tr.keypoints[:] = keypoints

        # Camera-local estimate with errors, lifted with the unscaled VO cameras.
        lifted_transl = np.zeros((n, 3))
        lifted_root = np.zeros((n, 3))
        depth_bias = 1.0 + depth_error * rng.normal()
        for i in range(n):
            cam_from_world = np.linalg.inv(world_from_cam[i])
            root_in_cam = cam_from_world[:3, :3] @ tr.transl[i] + cam_from_world[:3, 3]
            root_in_cam *= depth_bias * (1.0 + 0.03 * rng.normal())
            lifted_transl[i] = vo[i, :3, :3] @ root_in_cam + vo[i, :3, 3]
            r_cam = Rotation.from_matrix(cam_from_world[:3, :3]) * Rotation.from_rotvec(tr.root_orient[i])
            r_cam = Rotation.from_rotvec(rotation_error * rng.normal(size=3) / np.sqrt(3)) * r_cam
            lifted_root[i] = (Rotation.from_matrix(vo[i, :3, :3]) * r_cam).as_rotvec()
        body = tr.body_pose + pose_error * rng.normal(size=tr.body_pose.shape)
        betas = tr.betas + 0.3 * rng.normal(size=tr.betas.shape)
        # The ground as a camera-local estimate sees it: the world plane y = 0 in each frame's camera.
        normal_in_cam = np.einsum("tji,j->ti", world_from_cam[:, :3, :3], UP)
        offset_in_cam = world_from_cam[:, :3, 3] @ UP
        init.append(Track(0, keypoints, lifted_transl, lifted_root, body, betas, normal_in_cam, offset_in_cam,
                          tr.contacts.copy()))
    return SyntheticScene(fps, truth, init, cameras_true, cameras_vo, vo_scale, (W, H))


def _planted_root_path(model: BodyModel, root: np.ndarray, body: np.ndarray, betas: np.ndarray,
                       start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root translations that keep one foot joint planted: the body moves because the stance joint, fixed on the
    ground, pushes it, and the lower foot stands on y = 0 (its joint at its standing height above the sole,
    contact_rest_heights). Returns (transl n x 3, contacts n x 4), where contacts[i] marks the joint held still
    between frames i and i + 1 (the ground-truth contact labels)."""
    pose = np.concatenate([root[:, None], body], axis=1)
    # Contact joints relative to their standing heights, root at the origin.
    local = model.joints(pose, betas)[:, list(CONTACT_JOINTS)] - contact_rest_heights(model, betas)[:, None] * UP
    n = len(root)
    transl = np.zeros((n, 3))
    contacts = np.zeros((n, len(CONTACT_JOINTS)))
    transl[0] = start
    feet = [CONTACT_JOINTS.index(10), CONTACT_JOINTS.index(11)]  # the two foot joints; ankles never plant
    for i in range(1, n):
        stance = feet[int(np.argmin(local[i, feet, 1]))]  # the lower foot carries the weight
        transl[i, [0, 2]] = transl[i - 1, [0, 2]] + local[i - 1, stance, [0, 2]] - local[i, stance, [0, 2]]
        contacts[i - 1, stance] = 1.0
    contacts[n - 1] = contacts[n - 2] if n > 1 else 0.0
    # Vertical: the lower foot joint at its standing height (the foot on the ground), so the stance foot is
    # (nearly) still vertically too. (Placing the lowest of all four contact joints there instead lifts the stance
    # foot whenever the synthetic model's ankle dips, and the scale estimator's planted feet read 10% long.)
    transl[:, 1] = -local[:, feet, 1].min(axis=1)
    return transl, contacts
