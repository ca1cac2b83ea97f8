"""Metrics against hand-computed cases and an independent numerical similarity fit (scipy least squares)."""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from m3c.eval import metrics as M


def reference_similarity_error(pred, gt, with_scale=True):
    """Mean distance after the best similarity/rigid transform, found by generic least squares (not SVD)."""
    def residual(x):
        s = np.exp(x[0]) if with_scale else 1.0
        R = Rotation.from_rotvec(x[1:4]).as_matrix()
        return (s * pred @ R.T + x[4:7] - gt).ravel()

    best = None
    for start in Rotation.random(6, random_state=3).as_rotvec():  # several starts: no local minimum wins
        sol = least_squares(residual, np.concatenate([[0.0], start, gt.mean(0) - pred.mean(0)]), xtol=1e-14,
                            ftol=1e-14, gtol=1e-14)
        if best is None or sol.cost < best.cost:
            best = sol
    return np.linalg.norm(best.fun.reshape(-1, 3), axis=1).mean()


def test_umeyama_recovers_a_known_similarity(rng):
    src = rng.normal(size=(4, 14, 3))
    R = Rotation.random(4, random_state=1).as_matrix()
    s = np.array([0.5, 1.0, 2.0, 3.3])
    t = rng.normal(size=(4, 3))
    dst = s[:, None, None] * np.einsum("bij,bnj->bni", R, src) + t[:, None]
    s_hat, R_hat, t_hat = M.umeyama(src, dst)
    np.testing.assert_allclose(s_hat, s, rtol=1e-10)
    np.testing.assert_allclose(R_hat, R, atol=1e-10)
    np.testing.assert_allclose(t_hat, t, atol=1e-10)


def test_umeyama_never_returns_a_reflection(rng):
    src = rng.normal(size=(10, 3))
    mirrored = src * np.array([-1.0, 1.0, 1.0])
    _, R, _ = M.umeyama(src, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # The proper rotation is the least-squares one: compare with the generic fit.
    aligned = M.apply_similarity(*M.umeyama(src, mirrored), src)
    assert np.linalg.norm(aligned - mirrored, axis=1).mean() == pytest.approx(
        reference_similarity_error(src, mirrored), rel=1e-6)


def test_umeyama_rejects_a_point_set_without_spread():
    with pytest.raises(ValueError, match="no spread"):
        M.umeyama(np.ones((5, 3)), np.zeros((5, 3)))


def test_mpjpe_hand_computed():
    gt = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    pred = gt + np.array([5.0, -2.0, 7.0])  # a different root position: removed by the pelvis alignment
    np.testing.assert_allclose(M.mpjpe(pred, gt), [0.0], atol=1e-9)
    pred[0, 1] += [0.003, 0.004, 0.0]  # joint 1 off by 5 mm -> mean over 2 joints 2.5 mm
    np.testing.assert_allclose(M.mpjpe(pred, gt), [2.5], atol=1e-9)


def test_mpjpe_pelvis_is_the_mean_of_the_hips():
    gt = np.array([[[0.0, 1.0, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]]])
    pred = gt.copy()
    pred[0, 0] += [0.0, 0.03, 0.0]  # only the top joint moves: hips centre unchanged -> 30 mm / 3
    np.testing.assert_allclose(M.mpjpe(pred, gt, pelvis=(1, 2)), [10.0], atol=1e-9)
    # Aligned by joint 0 instead, the two hips are each 30 mm off: 60 / 3 = 20 mm.
    np.testing.assert_allclose(M.mpjpe(pred, gt, pelvis=(0,)), [20.0], atol=1e-9)


def test_pa_mpjpe_hand_computed_scale():
    # A square with one axis stretched 2x: no rotation helps, scale 0.6 is optimal (sum p.g / sum |p|^2 =
    # 6/10);
    # errors 0.4 m on the x points, 0.2 m on the y points: mean 0.3 m = 300 mm.
    gt = np.array([[[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]]])
    pred = np.array([[[1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -2.0, 0]]])
    np.testing.assert_allclose(M.pa_mpjpe(pred, gt), [300.0], rtol=1e-9)


def test_pa_mpjpe_is_zero_under_similarity_and_matches_generic_fit(rng):
    gt = rng.normal(size=(3, 14, 3)) * 0.3
    R = Rotation.random(3, random_state=2).as_matrix()
    pred = 1.7 * np.einsum("bij,bnj->bni", R, gt) + rng.normal(size=(3, 1, 3))
    np.testing.assert_allclose(M.pa_mpjpe(pred, gt), 0.0, atol=1e-9)
    noisy = pred + 0.02 * rng.normal(size=pred.shape)
    got = M.pa_mpjpe(noisy, gt)
    want = [1000 * reference_similarity_error(noisy[i], gt[i]) for i in range(3)]
    np.testing.assert_allclose(got, want, rtol=1e-5)


def test_pve_aligns_by_the_joint_pelvis():
    gj = np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    gv = np.array([[[0.0, 0.5, 0.0], [0.0, -0.5, 0.0], [1.0, 0.0, 0.0]]])
    shift = np.array([2.0, 0.0, 0.0])
    pj, pv = gj + shift, gv + shift
    pv[0, 2] += [0.0, 0.0, 0.006]  # 6 mm on one of 3 vertices
    np.testing.assert_allclose(M.pve(pv, gv, pj, gj), [2.0], atol=1e-9)


def test_accel_error_hand_computed():
    # Joint 1 accelerates by 1 mm/frame^2 in the prediction only; joint 0 (the pelvis) is fixed in both.
    n, fps = 6, 30.0
    t = np.arange(n)
    gt = np.zeros((n, 2, 3))
    gt[:, 1] = [0.0, 1.0, 0.0]
    pred = gt.copy()
    pred[:, 1, 0] = 0.5 * 0.001 * t ** 2
    err = M.accel_error(pred, gt, fps)
    assert err.shape == (n - 2,)
    np.testing.assert_allclose(err, 0.001 * fps ** 2 / 2, rtol=1e-9)  # 0.45 m/s^2: mean over 2 joints
    # The same acceleration of the whole body is removed by the pelvis alignment.
    whole = gt + (0.5 * 0.001 * t ** 2)[:, None, None] * np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(M.accel_error(whole, gt, fps), 0.0, atol=1e-12)
    valid = np.ones(n, bool)
    valid[3] = False  # stencils centred at 2, 3, 4 touch frame 3
    assert M.accel_error(pred, gt, fps, valid=valid).shape == (1,)


def test_w_mpjpe_aligns_each_segment_on_its_first_two_frames(rng):
    n, seg = 8, 4
    gt = rng.normal(size=(n, 5, 3))
    pred = np.empty_like(gt)
    R = Rotation.random(2, random_state=4).as_matrix()
    drift = 0.01 * np.array([0.0, 0.0, 1.0])
    expect = np.zeros(n)
    for k, (a, b) in enumerate([(0, 4), (4, 8)]):
        # Each segment: a different similarity, then a drift that starts after its first two frames.
        for i in range(a, b):
            steps = max(0, i - a - 1)
            pred[i] = (2.0 + k) * (gt[i] + steps * drift) @ R[k].T + k
            expect[i] = 10.0 * steps  # mm
    np.testing.assert_allclose(M.w_mpjpe(pred, gt, segment=seg), expect, atol=1e-9)


def test_wa_mpjpe_matches_generic_fit_per_segment(rng):
    n, seg = 10, 5
    gt = rng.normal(size=(n, 4, 3))
    pred = 0.8 * gt @ Rotation.random(random_state=5).as_matrix().T + 3.0 + 0.05 * rng.normal(size=gt.shape)
    got = M.wa_mpjpe(pred, gt, segment=seg)
    for a in (0, 5):
        p, g = pred[a:a + seg].reshape(-1, 3), gt[a:a + seg].reshape(-1, 3)
        # Per-frame values average to the segment's point mean (equal joints per frame).
        assert got[a:a + seg].mean() == pytest.approx(1000 * reference_similarity_error(p, g), rel=1e-5)


def test_rte_hand_computed():
    gt = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    pred = 2.0 * gt  # twice too fast: no scale in RTE; best shift -1 m -> errors 1, 0, 1 m over a 2 m path
    np.testing.assert_allclose(M.rte(pred, gt), [50.0, 0.0, 50.0], atol=1e-9)
    R = Rotation.from_rotvec([0.1, 0.7, -0.2]).as_matrix()
    np.testing.assert_allclose(M.rte(gt @ R.T + 4.0, gt), 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="does not move"):
        M.rte(gt, np.zeros((3, 3)))


def test_jitter_hand_computed():
    fps, c = 30.0, 1e-4
    t = np.arange(7, dtype=float)
    joints = np.zeros((7, 3, 3))
    joints[:, :, 1] = (c * t ** 3)[:, None]  # third difference of c t^3 is 6c
    np.testing.assert_allclose(M.jitter(joints, fps), 6 * c * fps ** 3, rtol=1e-9)  # 16.2 m/s^3


def test_foot_sliding_counts_only_ground_truth_contacts():
    gt = np.zeros((4, 1, 3))
    gt[:, 0, 0] = [0.0, 0.0, 0.5, 1.0]  # step 0-1 planted, steps 1-2 and 2-3 swing 50 cm
    pred = gt.copy()
    pred[1:, 0, 2] = [0.005, 0.010, 0.015]  # slides 5 mm per frame
    np.testing.assert_allclose(M.foot_sliding(pred, gt), [5.0], atol=1e-9)  # only step 0-1 is a contact


def test_camera_ate_is_zero_after_sim3_and_matches_generic_fit(rng):
    T = 12
    gt = np.tile(np.eye(4), (T, 1, 1))
    gt[:, :3, :3] = Rotation.random(T, random_state=6).as_matrix()
    gt[:, :3, 3] = np.cumsum(rng.normal(size=(T, 3)), axis=0)
    S = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    pred = gt.copy()
    pred[:, :3, :3] = S @ gt[:, :3, :3]
    pred[:, :3, 3] = 0.25 * gt[:, :3, 3] @ S.T + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(M.camera_ate(pred, gt), 0.0, atol=1e-8)
    trans, rot = M.camera_rpe(pred, gt, delta=2)
    np.testing.assert_allclose(trans, 0.0, atol=1e-8)
    np.testing.assert_allclose(rot, 0.0, atol=1e-5)
    pred[:, :3, 3] += 0.05 * rng.normal(size=(T, 3))
    assert M.camera_ate(pred, gt).mean() == pytest.approx(
        1000 * reference_similarity_error(pred[:, :3, 3], gt[:, :3, 3]), rel=1e-5)


def test_camera_rpe_hand_computed():
    gt = np.tile(np.eye(4), (4, 1, 1))
    gt[:, 0, 3] = [-1.5, -0.5, 0.5, 1.5]
    pred = gt.copy()
    pred[3, :3, :3] = Rotation.from_rotvec(np.radians(10) * np.array([0, 1.0, 0])).as_matrix()
    trans, rot = M.camera_rpe(pred, gt)  # centres untouched: alignment is the identity
    np.testing.assert_allclose(trans, 0.0, atol=1e-9)
    np.testing.assert_allclose(rot, [0.0, 0.0, 10.0], atol=1e-9)
    # Centre offsets (0, d, d, 0) along y: the rigid alignment shifts by -d/2, leaving -d/2, d/2, d/2, -d/2;
    # relative motions 0-1 and 2-3 are off by d, 1-2 by nothing; ATE is d/2 everywhere.
    d = 0.04
    pred = gt.copy()
    pred[[1, 2], 1, 3] = d
    trans, rot = M.camera_rpe(pred, gt, with_scale=False)
    np.testing.assert_allclose(trans, [40.0, 0.0, 40.0], atol=1e-9)
    np.testing.assert_allclose(M.camera_ate(pred, gt, with_scale=False), 20.0, atol=1e-9)


def test_shape_errors_name_the_fix():
    with pytest.raises(ValueError, match="common frames"):
        M.mpjpe(np.zeros((3, 4, 3)), np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match=r"\(n, J, 3\)"):
        M.pa_mpjpe(np.zeros((4, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        M.jitter(np.full((5, 2, 3), np.nan), 30.0)
