"""The WHAM-style world lift of one track (thesis Fig. 4.10): WHAM's motion encoder reads the 2D keypoints,
its trajectory decoder turns them and the camera's angular velocity into the root's world orientation and
velocity, and, when contacts are known, its trajectory refiner corrects both from contact-masked foot velocities.
Body pose and shape stay those of the local track (the thesis takes them from the camera-local regressor too).

WHAM's world is y-down; M3C's is y-up. FLIP (a half turn about x) maps M3C's world to a y-down one, in which
WHAM's initial root orientation and camera rotations are expressed, and back.
"""

from __future__ import annotations

import numpy as np
import torch

from m3c.body.joint_names import CONTACT_JOINTS
from m3c.models.rotations import matrix_to_rotation_6d_rows
from m3c.models.wham import camera_angular_velocity, keypoint_inputs
from scipy.spatial.transform import Rotation

FLIP = np.diag([1.0, -1.0, -1.0])  # y-up world -> y-down world (rotation by pi about x)


def _root_centred_keypoints(model, track: dict) -> np.ndarray:
    """COCO-17 keypoints (17, 3) of the first frame in the camera frame, minus the hips' midpoint."""
    pose = np.concatenate([track["root_orient"][:1, None], track["body_pose"][:1]], axis=1)
    kp = model.keypoints(model.coco17_regressor(), pose, track["betas"], track["transl"][:1])[0]
    return kp - kp[[11, 12]].mean(axis=0)


@torch.no_grad()
def wham_trajectory(lifter, model, track: dict, world_from_cam: np.ndarray, root_world: np.ndarray,
                    transl_world: np.ndarray, video: dict, intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Root orientation (n, 3) and translation (n, 3) of a camera-frame track in M3C's world.

    world_from_cam: (T, 4, 4) metric cameras in the world; root_world / transl_world: the camera lift of the
    track (n, 3), which fixes where the trajectory starts.
    """
    parameter = next(lifter.parameters())
    dtype, device = parameter.dtype, parameter.device
    frames = track["first_frame"] + np.arange(track["num_frames"])
    n = len(frames)
    if n < 2:
        return root_world, transl_world
    box = np.asarray(track["box"], dtype=np.float64)
    box3 = np.stack([(box[:, 0] + box[:, 2]) / 2, (box[:, 1] + box[:, 3]) / 2, box[:, 2] - box[:, 0]], axis=1)
    keypoints = np.asarray(track["keypoints"], dtype=np.float64)
    x, mask = keypoint_inputs(keypoints[..., :2], keypoints[..., 2], box3, (video["width"], video["height"]))
    x = x.to(dtype=dtype, device=device)[None]
    init_kp = torch.cat([torch.as_tensor(_root_centred_keypoints(model, track).reshape(1, 1, -1), dtype=dtype,
                                         device=device), x[:, :1]], dim=-1)
    root0 = FLIP @ Rotation.from_rotvec(root_world[0]).as_matrix()
    init_root = matrix_to_rotation_6d_rows(torch.as_tensor(root0, dtype=dtype, device=device)).reshape(1, 1, 6)
    cam_from_world = np.transpose(FLIP @ world_from_cam[frames, :3, :3], (0, 2, 1))
    angvel = camera_angular_velocity(torch.as_tensor(cam_from_world, dtype=dtype), float(video["fps"]))
    lifted = lifter.lift(x, mask[None].to(device), init_kp, init_root, angvel[None].to(device))
    lifted = {k: v.cpu() if isinstance(v, torch.Tensor) else v for k, v in lifted.items()}
    # M3C's own regressor (m3c.training.regressor) has no trajectory refiner.
    if track.get("contacts") is not None and hasattr(lifter, "trajectory_refiner"):
        feet = _feet_in_wham_world(model, track, lifted)
        lifted = lifter.refine({k: v.to(device) for k, v in lifted.items()},
                               torch.as_tensor(feet, dtype=dtype, device=device)[None],
                               torch.as_tensor(track["contacts"], dtype=dtype, device=device)[None])
        lifted = {k: v.cpu() for k, v in lifted.items()}
    R = FLIP.T @ lifted["root_world"][0].double().numpy()
    trans = lifted["trans_world"][0].double().numpy() @ FLIP  # FLIP.T @ t per row (FLIP is symmetric)
    root = Rotation.from_matrix(R).as_rotvec()
    # WHAM's trajectory is a displacement: start it where the camera lift put the person.
    return root, transl_world[0] + (trans - trans[0])


def _feet_in_wham_world(model, track: dict, lifted: dict) -> np.ndarray:
    """(n, 4, 3) foot joints of the track posed with WHAM's root orientation and translation (its world)."""
    root = Rotation.from_matrix(lifted["root_world"][0].double().numpy()).as_rotvec()
    pose = np.concatenate([root[:, None], track["body_pose"]], axis=1)
    return model.joints(pose, track["betas"], lifted["trans_world"][0].double().numpy())[:, list(CONTACT_JOINTS)]
