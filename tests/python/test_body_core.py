"""The C++ body core against the independent numpy reference (m3c.body.reference), and its Jacobians
against central finite differences."""

import numpy as np
import pytest

from m3c import _core
from m3c.body import BodyModel
from m3c.body import reference
from m3c.body.synthetic import random_pose


def test_forward_matches_reference_float64(synthetic_body_model, synthetic_model_data):
    pose = random_pose(4, seed=1)
    betas = np.random.default_rng(2).normal(size=(4, 10))
    transl = np.random.default_rng(3).normal(size=(4, 3))
    out = synthetic_body_model.forward(pose, betas, transl)
    ref_v, ref_j = reference.lbs(synthetic_model_data, pose, betas, transl)
    assert out.vertices.dtype == np.float64
    np.testing.assert_allclose(out.vertices, ref_v, rtol=0, atol=1e-10)
    np.testing.assert_allclose(out.joints, ref_j, rtol=0, atol=1e-10)


def test_forward_float32_matches_reference(synthetic_body_model, synthetic_model_data):
    pose = random_pose(3, seed=4)
    betas = np.random.default_rng(5).normal(size=10)
    out = synthetic_body_model.forward(pose.astype(np.float32), betas.astype(np.float32))
    ref_v, ref_j = reference.lbs(synthetic_model_data, pose, betas)
    assert out.vertices.dtype == np.float32 and out.joints.dtype == np.float32
    np.testing.assert_allclose(out.vertices, ref_v, rtol=0, atol=1e-5)
    np.testing.assert_allclose(out.joints, ref_j, rtol=0, atol=1e-5)


def test_joints_only_path_equals_skinned_joints(synthetic_body_model):
    pose = random_pose(500, seed=6)
    betas = np.random.default_rng(7).normal(size=10)
    fk = synthetic_body_model.joints(pose, betas, np.ones(3))
    out = synthetic_body_model.forward(pose, betas, np.ones(3))
    np.testing.assert_allclose(fk, out.joints, atol=1e-12)


def test_pose_layouts_and_broadcasting(synthetic_body_model):
    pose = random_pose(2, seed=8)
    betas = np.zeros(10)
    a = synthetic_body_model.forward(pose, betas, np.array([1.0, 2.0, 3.0]))
    b = synthetic_body_model.forward(pose.reshape(2, 72), np.zeros((2, 10)), np.tile([1.0, 2.0, 3.0], (2, 1)))
    np.testing.assert_array_equal(a.vertices, b.vertices)


def _finite_difference(fn, x, h=1e-6):
    cols = []
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        cols.append((fn(xp) - fn(xm)) / (2 * h))
    return np.stack(cols, axis=-1)


def _split(x, J=24):
    return x[3:3 + 3 * J], x[3 + 3 * J:], x[:3]


@pytest.mark.parametrize("pose_scale", [0.5, 1e-5, 0.0])
def test_joint_jacobian_matches_finite_differences(synthetic_body_model, pose_scale):
    rng = np.random.default_rng(9)
    x = np.concatenate([rng.normal(size=3), pose_scale * rng.normal(size=72), rng.normal(size=10)])
    pose, betas, transl = _split(x)
    joints, jac = synthetic_body_model.joints_jacobian(pose[None], betas, transl[None])

    def fn(xx):
        p, b, t = _split(xx)
        return reference.lbs_frame(synthetic_body_model.data, p, b, t)[1].reshape(-1)

    np.testing.assert_allclose(joints[0].reshape(-1), fn(x), atol=1e-10)
    np.testing.assert_allclose(jac[0], _finite_difference(fn, x), atol=1e-7)


def test_coco_style_keypoint_jacobian_matches_finite_differences(synthetic_body_model):
    model = synthetic_body_model
    rng = np.random.default_rng(10)
    vertex_weights = np.zeros((4, model.num_vertices))
    vertex_weights[0, 5] = 1.0
    vertex_weights[1, [100, 200, 300]] = [0.2, 0.3, 0.5]
    joint_weights = np.zeros((4, 24))
    joint_weights[2, 20] = 1.0
    joint_weights[3, [7, 10]] = 0.5
    reg = model.regressor(vertex_weights, joint_weights)
    x = np.concatenate([rng.normal(size=3), 0.6 * rng.normal(size=72), rng.normal(size=10)])
    pose, betas, transl = _split(x)
    kp, jac = model.keypoints_jacobian(reg, pose[None], betas, transl[None])

    def fn(xx):
        p, b, t = _split(xx)
        verts, joints = reference.lbs_frame(model.data, p, b, t)
        return (vertex_weights @ verts + joint_weights @ joints).reshape(-1)

    np.testing.assert_allclose(kp[0].reshape(-1), fn(x), atol=1e-10)
    np.testing.assert_allclose(jac[0], _finite_difference(fn, x), atol=1e-7)
    # The batched keypoints path agrees with the Jacobian path.
    np.testing.assert_allclose(model.keypoints(reg, pose[None], betas, transl[None]), kp, atol=1e-12)


def test_vertex_selection_equals_mesh_vertices(synthetic_body_model):
    ids = [0, 17, 400]
    pose = random_pose(3, seed=11)
    betas = np.zeros(10)
    sel = synthetic_body_model.keypoints(synthetic_body_model.vertex_selection(ids), pose, betas)
    verts = synthetic_body_model.forward(pose, betas).vertices
    np.testing.assert_allclose(sel, verts[:, ids], atol=1e-12)


def test_shape_errors_name_the_expected_shape(synthetic_body_model):
    with pytest.raises(ValueError, match=r"pose must have shape \(N, 24, 3\) or \(N, 72\), got \(2, 23, 3\)"):
        synthetic_body_model.forward(np.zeros((2, 23, 3)), np.zeros(10))
    with pytest.raises(ValueError, match=r"betas must have shape \(10,\) or \(N=2, 10\)"):
        synthetic_body_model.forward(np.zeros((2, 24, 3)), np.zeros(11))
    with pytest.raises(ValueError, match=r"transl must have shape"):
        synthetic_body_model.forward(np.zeros((2, 24, 3)), np.zeros(10), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="must be a float array"):
        synthetic_body_model.forward(np.array([["a"] * 72]), np.zeros(10))


def test_core_model_validates_arrays(synthetic_model_data):
    d = synthetic_model_data
    with pytest.raises(ValueError, match="posedirs must have shape"):
        _core.BodyModel(d.v_template, d.shapedirs, d.posedirs[:, :, :10], d.J_regressor, d.weights, d.parents,
                        d.faces)
    bad_parents = d.parents.copy()
    bad_parents[5] = 7
    with pytest.raises(ValueError, match="every parent must come before its child"):
        _core.BodyModel(d.v_template, d.shapedirs, d.posedirs, d.J_regressor, d.weights, bad_parents, d.faces)


def test_any_vertex_and_joint_count():
    # A 3-joint chain with 5 vertices: nothing assumes SMPL's sizes.
    rng = np.random.default_rng(12)
    V, J, B = 5, 3, 2
    from m3c.body import BodyModelData

    weights = rng.uniform(size=(V, J))
    weights /= weights.sum(1, keepdims=True)
    reg = rng.uniform(size=(J, V))
    reg /= reg.sum(1, keepdims=True)
    data = BodyModelData(rng.normal(size=(V, 3)), rng.normal(size=(V, 3, B)), 0.1 * rng.normal(size=(V, 3, 18)),
                         reg, weights, np.array([-1, 0, 1]), np.zeros((0, 3), np.int32))
    model = BodyModel(data)
    pose = rng.normal(size=(2, J, 3))
    betas = rng.normal(size=B)
    out = model.forward(pose, betas)
    ref_v, ref_j = reference.lbs(data, pose, betas)
    np.testing.assert_allclose(out.vertices, ref_v, atol=1e-10)
    np.testing.assert_allclose(out.joints, ref_j, atol=1e-10)


def test_torch_lbs_matches_reference(synthetic_model_data):
    torch = pytest.importorskip("torch")
    from m3c.body.torch_lbs import TorchBodyModel

    pose = random_pose(3, seed=13)
    betas = np.random.default_rng(14).normal(size=(3, 10))
    transl = np.random.default_rng(15).normal(size=(3, 3))
    tm = TorchBodyModel(synthetic_model_data, dtype=torch.float64)
    v, j = tm(torch.as_tensor(pose), torch.as_tensor(betas), torch.as_tensor(transl))
    ref_v, ref_j = reference.lbs(synthetic_model_data, pose, betas, transl)
    np.testing.assert_allclose(v.numpy(), ref_v, atol=1e-10)
    np.testing.assert_allclose(j.numpy(), ref_j, atol=1e-10)
