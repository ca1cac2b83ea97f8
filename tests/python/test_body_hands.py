"""The open body model's hands (m3c.body.hands, data/m3c_open_hands.npz): SMPL-H finger layout, rest joints
that agree with the body, skinning weights that split the body's hand joint, and forward kinematics and
skinning checked against the independent numpy LBS reference (m3c.body.reference, matrix-exponential
rotations) run on a 52-joint SMPL-H-layout model assembled from the two files."""

from dataclasses import replace

import numpy as np
import pytest
from m3c.body import BodyModel, BodyModelData, open_body_model_data
from m3c.body.hands import (
    HAND_JOINT_NAMES,
    HAND_JOINTS,
    HAND_PARENTS,
    MEDIAPIPE_FROM_HAND,
    SIDES,
    SMPLH_FIRST_FINGER_JOINT,
    TIP_JOINTS,
    load_hand_model,
    pose_hands,
    skin_hands,
    wrist_frames,
)
from m3c.body.joint_names import SMPL_PARENTS
from m3c.body.layouts import to_smpl_layout
from m3c.body.reference import lbs

RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def hand():
    return load_hand_model()


@pytest.fixture(scope="module")
def body():
    return open_body_model_data()


def test_layout_is_smplh():
    assert HAND_JOINT_NAMES[:3] == ("index1", "index2", "index3")
    assert HAND_JOINT_NAMES[6:9] == ("pinky1", "pinky2", "pinky3")
    assert HAND_JOINT_NAMES[-3:] == ("thumb1", "thumb2", "thumb3")
    assert len(HAND_JOINT_NAMES) == 15 and HAND_PARENTS[:3] == (-1, 0, 1)
    assert sorted(MEDIAPIPE_FROM_HAND) == list(range(21))


def test_rest_hands_agree_with_the_body(hand, body):
    J = body.J_regressor @ body.v_template
    for s, side in enumerate(SIDES):
        sign = 1.0 if side == "left" else -1.0
        np.testing.assert_allclose(hand.wrist_template[s], J[HAND_JOINTS[side] - 2], atol=1e-6)
        # The body's hand joint is the mean of the four knuckles (index, middle, pinky, ring 1).
        knuckles = hand.joints_template[s][[0, 3, 6, 9]].mean(axis=0)
        np.testing.assert_allclose(knuckles, J[HAND_JOINTS[side]], atol=2e-4)
        along = sign * (hand.joints_template[s][:, 0] - hand.wrist_template[s, 0])
        assert np.all(along > 0.02) and np.all(along < 0.2)  # T-pose: fingers out along +-x
        tips = sign * hand.tips_template[s][:, 0]
        assert np.all(tips > sign * hand.joints_template[s][list(TIP_JOINTS), 0])
        # Every finger bone is 1.5-6 cm long.
        for j, p in enumerate(HAND_PARENTS):
            if p >= 0:
                assert 0.015 < np.linalg.norm(hand.joints_template[s, j] - hand.joints_template[s, p]) < 0.06
    np.testing.assert_allclose(hand.joints_template[1] * [-1, 1, 1], hand.joints_template[0], atol=1e-4)
    # Along the shape space the knuckles follow the body's hand joint (its regressor), within 1.5 mm per beta.
    Jdirs = np.einsum("jv,vcb->jcb", body.J_regressor, body.shapedirs)
    for s, side in enumerate(SIDES):
        knuckle_dirs = hand.joints_shapedirs[s][[0, 3, 6, 9]].mean(axis=0)
        assert np.abs(knuckle_dirs - Jdirs[HAND_JOINTS[side]]).max() < 1.5e-3


def test_finger_weights_split_the_hand_joint(hand, body):
    for side in SIDES:
        ids, w = hand.vertex_ids[side], hand.weights[side]
        assert np.all(w >= 0)
        np.testing.assert_allclose(w.sum(axis=1), body.weights[ids, HAND_JOINTS[side]], atol=1e-5)
        others = np.setdiff1d(np.arange(body.num_vertices), ids)
        assert np.all(body.weights[others, HAND_JOINTS[side]] == 0)
        assert np.all(w.max(axis=0) > 0.5)  # every finger bone carries some vertices


def smplh_reference(body: BodyModelData, hand) -> tuple[BodyModelData, int]:
    """A 52-joint SMPL-H-layout model: the body's vertices, then one point at every rest finger joint and tip
    (their shape directions from the hand model, rigid on their joint), finger joints regressed from those
    points, and the body's hand-joint weights split onto the fingers."""
    V, B = body.num_vertices, body.num_betas
    points = np.concatenate([hand.joints_template.reshape(-1, 3), hand.tips_template.reshape(-1, 3)])
    point_dirs = np.concatenate([hand.joints_shapedirs.reshape(-1, 3, B),
                                 hand.tips_shapedirs.reshape(-1, 3, B)])
    N = V + len(points)
    weights = np.zeros((N, 52))
    weights[:V, :22] = body.weights[:, :22]
    regressor = np.zeros((52, N))
    regressor[:22, :V] = body.J_regressor[:22]
    parents = list(SMPL_PARENTS[:22])
    for s, side in enumerate(SIDES):
        first = SMPLH_FIRST_FINGER_JOINT[side]
        parents += [HAND_JOINTS[side] - 2 if p < 0 else first + p for p in HAND_PARENTS]
        weights[hand.vertex_ids[side], first:first + 15] = hand.weights[side]
        for j in range(15):
            regressor[first + j, V + 15 * s + j] = 1.0
            weights[V + 15 * s + j, first + j] = 1.0
        for f, j in enumerate(TIP_JOINTS):
            weights[V + 30 + 5 * s + f, first + j] = 1.0
    data = BodyModelData(
        v_template=np.concatenate([body.v_template, points]),
        shapedirs=np.concatenate([body.shapedirs, point_dirs]),
        posedirs=np.zeros((N, 3, 51 * 9)), J_regressor=regressor, weights=weights,
        parents=np.asarray(parents), faces=body.faces, name="open+hands (SMPL-H layout)")
    return data, V


def random_poses(n: int):
    body_pose = np.zeros((n, 24, 3))
    body_pose[:, :22] = RNG.normal(0, 0.3, (n, 22, 3))
    hand_pose = RNG.normal(0, 0.4, (n, 2, 15, 3))
    return body_pose, hand_pose


def test_forward_kinematics_and_skinning_match_the_reference(hand, body):
    reference, V = smplh_reference(body, hand)
    model = BodyModel(body)
    n = 3
    body_pose, hand_pose = random_poses(n)
    betas = RNG.normal(0, 1, 10)
    transl = RNG.normal(0, 1, 3)
    smplh_pose = np.concatenate([body_pose[:, :22], hand_pose.reshape(n, 30, 3)], axis=1)
    ref_vertices, ref_joints = lbs(reference, smplh_pose, betas, transl)
    rotation, position = wrist_frames(model, body_pose, betas, transl)
    posed = pose_hands(hand, betas, rotation, position, hand_pose)
    for s, side in enumerate(SIDES):
        first = SMPLH_FIRST_FINGER_JOINT[side]
        np.testing.assert_allclose(posed.joints[:, s], ref_joints[:, first:first + 15], atol=1e-6)
        tips = ref_vertices[:, V + 30 + 5 * s:V + 35 + 5 * s]
        np.testing.assert_allclose(posed.tips[:, s], tips, atol=1e-6)
        np.testing.assert_allclose(posed.wrists[:, s], ref_joints[:, HAND_JOINTS[side] - 2], atol=1e-6)
    keypoints = posed.keypoints()
    assert keypoints.shape == (n, 2, 21, 3)
    np.testing.assert_allclose(keypoints[:, :, 8], posed.tips[:, :, 0])  # MediaPipe 8: the index tip
    np.testing.assert_allclose(keypoints[:, :, 1], posed.joints[:, :, 12])  # 1: the thumb's first joint
    out = model.forward(body_pose, betas, transl)
    rest = body.v_template + body.shapedirs @ betas
    vertices = skin_hands(hand, betas, rest, out.vertices, rotation, position, hand_pose)
    np.testing.assert_allclose(vertices, ref_vertices[:, :V], atol=2e-5)
    # Flat hands change nothing.
    flat = skin_hands(hand, betas, rest, out.vertices, rotation, position, np.zeros_like(hand_pose))
    np.testing.assert_allclose(flat, out.vertices, atol=1e-5)


def test_smplh_reference_reduces_to_the_24_joint_body(hand, body):
    """SMPL-H files still load into the 24-joint layout; the assembled open SMPL-H model reduces to the
    body."""
    reference, V = smplh_reference(body, hand)
    reduced = to_smpl_layout(replace(reference, posedirs=np.zeros((reference.num_vertices, 3, 51 * 9))))
    assert reduced.num_joints == 24
    np.testing.assert_allclose(reduced.weights[:V], body.weights, atol=1e-5)
    J = (reduced.J_regressor @ reduced.v_template)[:24]
    np.testing.assert_allclose(J, body.J_regressor @ body.v_template, atol=2e-4)


@pytest.mark.slow
def test_rebuild_from_makehuman_assets_reproduces_the_shipped_hands():
    import importlib.util
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    path = repo / "tools" / "build_open_hand_model.py"
    spec = importlib.util.spec_from_file_location("build_open_hand_model", path)
    tool = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = tool
    spec.loader.exec_module(tool)
    assets = tool.load_body_builder().default_assets()
    if not (assets / "base.obj").is_file():
        pytest.skip(f"MakeHuman hm08 assets not found at {assets}; the shipped hand model is tested above")
    arrays, _, report = tool.build(assets, verbose=False)
    for side in SIDES:
        assert report["hands"][side]["weight_error"] < 1e-6
    with np.load(tool.DEFAULT_OUT) as shipped:
        assert sorted(shipped.files) == sorted(arrays)
        for key in arrays:
            if arrays[key].dtype.kind == "f":
                np.testing.assert_allclose(shipped[key], arrays[key], rtol=0, atol=2e-5, err_msg=key)
            else:
                np.testing.assert_array_equal(shipped[key], arrays[key], err_msg=key)
