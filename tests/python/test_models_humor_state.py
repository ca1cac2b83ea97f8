"""HuMoR's state builder and canonical frame, checked against closed forms, scipy rotations and the C++ body
model (an independent forward-kinematics implementation)."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m3c.body.torch_lbs import TorchBodyModel
from m3c.models import humor_state as hs
from m3c.models.rotations import matrix_to_axis_angle

FPS = 30.0


def smooth_motion(T, seed, upright=True):
    """SMPL parameters of a smooth random motion in a z-up ground frame: trans (T,3), root (T,3),
    body pose (T,21,3) axis-angle."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / FPS
    trans = np.stack([0.8 * t + 0.1 * np.sin(3 * t), 0.3 * np.cos(2 * t), 0.9 + 0.05 * np.sin(5 * t)], 1)
    heading = Rotation.from_rotvec(np.outer(0.6 * t + 0.4, [0, 0, 1]))
    wobble = Rotation.from_rotvec(0.1 * np.stack([np.sin(4 * t), np.cos(3 * t), 0 * t], 1))
    stand = Rotation.from_rotvec([math.pi / 2, 0, 0]) if upright else Rotation.identity()  # model y-up -> z-up
    root = (heading * wobble * stand).as_rotvec()
    phase = rng.uniform(0, 2 * np.pi, size=(21, 3))
    amp = rng.uniform(0.05, 0.4, size=(21, 3))
    pose = amp * np.sin(2.0 * t[:, None, None] + phase)
    return trans, root, pose


def smpl_joints(body, trans, root, pose):
    T = trans.shape[0]
    full = np.concatenate([root[:, None], pose, np.zeros((T, 2, 3))], axis=1)
    return body.joints(full, np.zeros(body.num_betas), trans)


def test_state_layout_and_velocities_match_closed_forms():
    T = 7
    t = np.arange(T) / FPS
    a, b, c = np.array([0.1, -0.2, 0.9]), np.array([1.0, 0.5, -0.1]), np.array([0.3, -0.6, 0.2])
    trans = a + np.outer(t, b) + np.outer(t * t, c)  # quadratic: the central difference is exact
    omega = np.array([0.4, -1.2, 2.0])
    R0 = Rotation.from_rotvec([0.3, 0.2, -0.5])
    root = (Rotation.from_rotvec(np.outer(t, omega)) * R0).as_rotvec()  # R(t) = Exp(t w) R0
    pose = np.random.default_rng(0).normal(scale=0.4, size=(T, 21, 3))
    joints = np.random.default_rng(1).normal(size=(22, 3)) + np.outer(t, b)[:, None] + np.outer(t * t, c)[:, None]
    x = hs.build_states(trans, root, pose, joints, fps=FPS).numpy()
    assert x.shape == (T - 2, 339)
    np.testing.assert_allclose(x[:, hs.TRANS], trans[1:-1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(x[:, hs.TRANS_VEL], b + 2 * np.outer(t[1:-1], c), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(x[:, hs.ROOT_ORIENT], Rotation.from_rotvec(root[1:-1]).as_matrix().reshape(-1, 9),
                               atol=1e-14)
    # (Exp(hw) - Exp(-hw)) / 2h = [w]x sin(h|w|) / (h|w|): the estimate is w scaled by sinc, exactly.
    h, norm = 1 / FPS, np.linalg.norm(omega)
    np.testing.assert_allclose(x[:, hs.ROOT_ORIENT_VEL], np.tile(omega * np.sin(h * norm) / (h * norm), (T - 2, 1)),
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x[:, hs.POSE_BODY],
                               Rotation.from_rotvec(pose[1:-1].reshape(-1, 3)).as_matrix().reshape(T - 2, 189),
                               atol=1e-14)
    np.testing.assert_allclose(x[:, hs.JOINTS], joints[1:-1, :22].reshape(T - 2, 66), atol=1e-15)
    np.testing.assert_allclose(x[:, hs.JOINTS_VEL].reshape(T - 2, 22, 3),
                               np.broadcast_to((b + 2 * np.outer(t[1:-1], c))[:, None], (T - 2, 22, 3)),
                               rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("normal", [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.2, -0.9, 0.3], [1.0, 0.0, 0.0]])
def test_ground_from_plane(normal):
    n = np.array(normal) / np.linalg.norm(normal)
    offset = 0.7
    R, t = (v.numpy() for v in hs.ground_from_plane(n * 2.0, offset * 2.0))  # any scale of (n, offset)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(R @ n, [0, 0, 1], atol=1e-14)
    rng = np.random.default_rng(2)
    points = rng.normal(size=(5, 3))
    heights = (R @ points.T).T[:, 2] + t[2]
    np.testing.assert_allclose(heights, points @ n + offset, atol=1e-14)  # signed distance to the plane
    with pytest.raises(ValueError, match="non-zero"):
        hs.ground_from_plane([0.0, 0.0, 0.0], 1.0)


def test_world_frame_with_ground_plane_matches_ground_frame(synthetic_body_model):
    """A motion captured in a tilted, shifted world frame, with its floor plane, gives the same canonical
    HuMoR states as the same motion built directly in the ground frame. Joints come from the C++ body model
    in each frame independently."""
    body = synthetic_body_model
    T = 8
    trans_g, root_g, pose = smooth_motion(T, seed=3)
    joints_g = smpl_joints(body, trans_g, root_g, pose)
    # world_from_ground: a rotation that tilts the up axis and a shift; the body is moved by SMPL's rule.
    Q = Rotation.from_rotvec([0.9, -0.4, 0.3])
    p = np.array([0.5, -1.2, 2.0])
    j0 = smpl_joints(body, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 21, 3)))[0, 0]
    root_w = (Q * Rotation.from_rotvec(root_g)).as_rotvec()
    trans_w = Q.apply(trans_g + j0) + p - j0
    joints_w = smpl_joints(body, trans_w, root_w, pose)
    np.testing.assert_allclose(joints_w, Q.apply(joints_g.reshape(-1, 3)).reshape(joints_g.shape) + p, atol=1e-12)

    up = Q.apply([0, 0, 1])
    ground = hs.ground_from_plane(up, -up @ p)
    x_g = hs.build_states(trans_g, root_g, pose, joints_g, fps=FPS)
    x_w = hs.build_states(trans_w, root_w, pose, joints_w, fps=FPS, ground_from_world=ground)
    # Heights agree; headings differ by the free yaw of the ground frame, which canonicalisation removes.
    np.testing.assert_allclose(x_w[:, 2].numpy(), x_g[:, 2].numpy(), atol=1e-12)
    for a, b in zip(hs.canonicalize_pair(x_w[:-1], x_w[1:]), hs.canonicalize_pair(x_g[:-1], x_g[1:])):
        np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-11)
    # One transform per frame (all equal here) is the same computation.
    R, t = ground
    per_frame = (R.expand(T, 3, 3), t.expand(T, 3))
    x_pf = hs.build_states(trans_w, root_w, pose, joints_w, fps=FPS, ground_from_world=per_frame)
    np.testing.assert_allclose(x_pf.numpy(), x_w.numpy(), atol=1e-15)


def test_build_states_from_body_matches_cpp_joints(synthetic_model_data, synthetic_body_model):
    T = 6
    trans, root, pose = smooth_motion(T, seed=4)
    betas = np.random.default_rng(5).normal(scale=0.5, size=10)
    torch_body = TorchBodyModel(synthetic_model_data, dtype=torch.float64)
    x = hs.build_states_from_body(torch_body, trans, root, pose, betas, fps=FPS)
    full = np.concatenate([root[:, None], pose, np.zeros((T, 2, 3))], axis=1)
    joints = synthetic_body_model.joints(full, betas, trans)
    np.testing.assert_allclose(x[:, hs.JOINTS].numpy(), joints[1:-1, :22].reshape(T - 2, 66), atol=1e-12)


def test_canonical_frame_properties():
    trans, root, pose = smooth_motion(6, seed=6)
    joints = np.random.default_rng(7).normal(size=(6, 22, 3)) + trans[:, None]
    x = hs.build_states(trans, root, pose, joints, fps=FPS)
    frame = hs.canonical_frame(x)
    xc = hs.to_canonical(x, frame)
    np.testing.assert_allclose(xc[:, 0:2].numpy(), 0, atol=1e-14)
    np.testing.assert_allclose(xc[:, 2].numpy(), x[:, 2].numpy(), atol=1e-15)
    Rc = xc[:, hs.ROOT_ORIENT].reshape(-1, 3, 3).numpy()
    assert np.all(-Rc[:, 0, 0] > 0)  # the body's right direction points along +x
    np.testing.assert_allclose(Rc[:, 1, 0], 0, atol=1e-14)
    # The rotation is the yaw that takes the right direction's heading to 0 (scipy, independent).
    R = x[:, hs.ROOT_ORIENT].reshape(-1, 3, 3).numpy()
    heading = np.arctan2(-R[:, 1, 0], -R[:, 0, 0])
    np.testing.assert_allclose(frame.rotation.numpy(), Rotation.from_euler("z", -heading[:, None]).as_matrix(), atol=1e-14)
    # Joints keep their offset from the translation's vertical after the turn about the pelvis.
    pelvis_offset = x[:, hs.JOINTS][:, :2] - x[:, 0:2]
    np.testing.assert_allclose((xc[:, hs.JOINTS][:, :2] - xc[:, 0:2]).numpy(), pelvis_offset.numpy(), atol=1e-14)
    # The inverse.
    np.testing.assert_allclose(hs.from_canonical(xc, frame).numpy(), x.numpy(), atol=1e-14)
    # Pairs use the first state's frame for both.
    a, b = hs.canonicalize_pair(x[:-1], x[1:])
    np.testing.assert_allclose(a.numpy(), xc[:-1].numpy(), atol=1e-15)
    np.testing.assert_allclose(b.numpy(), hs.to_canonical(x[1:], hs.canonical_frame(x[:-1])).numpy(), atol=1e-15)


def test_state_to_smpl_inverts_builder():
    trans, root, pose = smooth_motion(5, seed=8)
    joints = np.random.default_rng(9).normal(size=(5, 22, 3))
    x = hs.build_states(trans, root, pose, joints, fps=FPS)
    smpl = hs.state_to_smpl(x)
    np.testing.assert_allclose(smpl["trans"].numpy(), trans[1:-1], atol=1e-15)
    np.testing.assert_allclose(smpl["root_orient"].numpy(), root[1:-1], atol=1e-12)
    np.testing.assert_allclose(smpl["pose_body"].numpy(), pose[1:-1], atol=1e-12)
    np.testing.assert_allclose(smpl["joints"].numpy(), joints[1:-1], atol=1e-15)


def test_matrix_to_axis_angle_matches_scipy():
    rng = np.random.default_rng(10)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, 194), [0.0, 1e-9, 1e-5, np.pi - 1e-6, np.pi - 1e-9, 2.5]])
    rotvec = axes * angles[:, None]
    mats = Rotation.from_rotvec(rotvec).as_matrix()
    got = matrix_to_axis_angle(torch.from_numpy(mats)).numpy()
    # Compare as rotations (axis-angle is double-valued at pi).
    np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), mats, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), angles, atol=1e-8)
    ok = angles < np.pi - 1e-3
    np.testing.assert_allclose(got[ok], rotvec[ok], atol=1e-12)


def test_bad_inputs_name_the_shape():
    trans, root, pose = smooth_motion(5, seed=11)
    joints = np.zeros((5, 22, 3))
    with pytest.raises(ValueError, match=r"trans must have shape \(T >= 3, 3\)"):
        hs.build_states(trans[:2], root[:2], pose[:2], joints[:2])
    with pytest.raises(ValueError, match=r"pose_body must have shape \(T, 21, 3\)"):
        hs.build_states(trans, root, pose[:, :20], joints)
    with pytest.raises(ValueError, match=r"joints must have shape \(T=5, >=22, 3\)"):
        hs.build_states(trans, root, pose, joints[:, :21])
    with pytest.raises(ValueError, match="fps must be positive"):
        hs.build_states(trans, root, pose, joints, fps=0)
