"""The per-frame hand fit (m3c.perception.hand_fit) on synthetic hands: the open model's fingers posed from
known degrees of freedom (within the joint limits), the wrist's rotation off by a few degrees, projected by a
camera with 1 px of landmark noise; the fit must recover the 21 hand points after Procrustes on the hand."""

import numpy as np
import pytest
from m3c.body import BodyModel, open_body_model_data
from m3c.body.hands import SIDES, load_hand_model, pose_hands, wrist_frames
from m3c.camera import look_at, project, to_camera
from m3c.perception.hand_fit import (
    LOWER,
    NUM_DOFS,
    UPPER,
    SideModel,
    dofs_to_pose,
    fit_hand,
    hand_axes,
    smooth_dofs,
)
from scipy.spatial.transform import Rotation

K = np.array([1000.0, 1000.0, 480.0, 270.0])


@pytest.fixture(scope="module")
def setup():
    hand = load_hand_model()
    model = BodyModel(open_body_model_data())
    pose = np.zeros((1, 24, 3))
    # Arms down, the left elbow bent.
    pose[0, 16], pose[0, 17], pose[0, 18] = [0, 0, -1.2], [0, 0, 1.2], [0, -0.8, 0]
    rotation, position = wrist_frames(model, pose, np.zeros(10))
    return hand, rotation[0], position[0]


def procrustes_errors(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-point distances after the similarity transform that best aligns estimate onto truth."""
    a, b = estimate - estimate.mean(axis=0), truth - truth.mean(axis=0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.sum(S * np.diag(D)) / np.sum(a * a)
    return np.linalg.norm(s * a @ R.T - b, axis=1)


def test_axes_are_orthonormal_and_flexion_curls_towards_the_palm(setup):
    hand, _, _ = setup
    axes = hand_axes(hand, np.zeros(10))
    np.testing.assert_allclose(np.einsum("sjab,sjcb->sjac", axes, axes),
                               np.broadcast_to(np.eye(3), axes.shape), atol=1e-9)
    model = SideModel(hand, np.zeros(10), "left")
    rest = model.landmarks(np.zeros((1, NUM_DOFS)), np.eye(3)[None], np.zeros(3))[0]
    curled_dofs = np.zeros((1, NUM_DOFS))
    curled_dofs[0, [0, 2, 3]] = 0.5  # index: first joint, second, third flexed
    curled = model.landmarks(curled_dofs, np.eye(3)[None], np.zeros(3))[0]
    assert curled[8, 1] < rest[8, 1] - 0.03  # the index tip goes down, to the palm side (palms face -y)
    np.testing.assert_allclose(curled[12], rest[12])  # the middle finger stays
    # The batched landmark model agrees with pose_hands (the forward kinematics tested against the reference).
    dofs = np.random.default_rng(1).uniform(LOWER, UPPER)
    pose = np.zeros((1, 2, 15, 3))
    pose[0, 0] = dofs_to_pose(dofs, axes[0])
    out = pose_hands(hand, np.zeros(10), np.eye(3)[None, None].repeat(2, 1), np.zeros((1, 2, 3)), pose)
    np.testing.assert_allclose(model.landmarks(dofs[None], np.eye(3)[None], np.zeros(3))[0],
                               out.keypoints()[0, 0], atol=1e-9)


@pytest.mark.parametrize("side", [0, 1])
def test_fit_recovers_synthetic_hands(setup, side):
    hand, rotation, position = setup
    rng = np.random.default_rng(side)
    model = SideModel(hand, np.zeros(10), SIDES[side])
    cam = look_at(position[side] + np.array([0.3, -0.2, 1.5]), position[side])
    errors, baseline = [], []
    for _ in range(12):
        dofs = rng.uniform(0.8 * LOWER, 0.8 * UPPER)
        wrist = rotation[side] @ Rotation.from_rotvec(rng.normal(0, 0.15, 3)).as_matrix()
        truth = model.landmarks(dofs[None], wrist[None], position[side])[0]
        observed = np.c_[project(to_camera(truth, cam), K) + rng.normal(0, 1.0, (21, 2)), np.full(21, 0.9)]
        fit = fit_hand(model, observed, rotation[side], position[side], cam, K)
        assert fit.rms_px < 3.0
        fitted_wrist = rotation[side] @ Rotation.from_rotvec(fit.wrist_correction).as_matrix()
        estimate = model.landmarks(fit.dofs[None], fitted_wrist[None], position[side])[0]
        errors.append(procrustes_errors(estimate, truth).mean())
        rest = model.landmarks(np.zeros((1, NUM_DOFS)), rotation[side][None], position[side])[0]
        baseline.append(procrustes_errors(rest, truth).mean())
        assert np.all(fit.dofs >= LOWER - 1e-9) and np.all(fit.dofs <= UPPER + 1e-9)
    # Hands are about 18 cm long; the fit is within 2 cm per point on average, well below the rest hand.
    assert np.mean(errors) < 0.02
    assert np.mean(errors) < 0.5 * np.mean(baseline)


def test_unusable_observations_give_no_fit(setup):
    hand, rotation, position = setup
    model = SideModel(hand, np.zeros(10), "left")
    observed = np.zeros((21, 3))
    assert fit_hand(model, observed, rotation[0], position[0], np.eye(4), K) is None


def test_smoothing_stays_within_runs():
    values = np.zeros((10, 2))
    values[5:] = 1.0
    found = np.ones(10, bool)
    found[4] = False
    out = smooth_dofs(values, found)
    assert np.isnan(out[4]).all()
    np.testing.assert_allclose(out[:4], 0.0)
    np.testing.assert_allclose(out[5:], 1.0)
    noisy = np.random.default_rng(0).normal(0, 1, (50, 1))
    smoothed = smooth_dofs(noisy, np.ones(50, bool))
    assert np.std(np.diff(smoothed, axis=0)) < 0.3 * np.std(np.diff(noisy, axis=0))
