"""Plausibility figures of world motion against constructed motions with known answers and real motion capture."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body import default_body_model
from m3c.eval.benchmark import load_clips
from m3c.eval.plausibility import FOOT_JOINT_HEIGHT, results_plausibility, track_plausibility


def _walker(n=90, fps=30.0, speed=1.0):
    """A pelvis gliding along +x at `speed`, the left foot planted for the first half, the right for the rest."""
    t = np.arange(n) / fps
    joints = np.zeros((n, 24, 3))
    joints[:, :, 1] = 1.0
    joints[:, :, 0] = (speed * t)[:, None]
    for j, h in FOOT_JOINT_HEIGHT.items():
        joints[:, j, 1] = h
    half = n // 2
    for ankle, foot, planted in ((7, 10, slice(0, half)), (8, 11, slice(half, n))):
        for j in (ankle, foot):
            joints[planted, j, 0] = joints[planted, j, 0][0]
    return joints


def test_known_motion():
    joints = _walker()
    f = track_plausibility(joints, 30.0)
    assert f["mean_speed_mps"] == pytest.approx(1.0, abs=0.02)
    assert f["path_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert f["slow_foot_speed_mps"] == pytest.approx(0.0, abs=1e-9)
    assert f["below_ground_fraction"] == 0.0 and f["penetration_m"] == pytest.approx(0.0, abs=1e-12)
    sunk = joints.copy()
    sunk[..., 1] -= 0.1
    g = track_plausibility(sunk, 30.0)
    assert g["below_ground_fraction"] == 1.0 and g["penetration_m"] == pytest.approx(0.1)
    # The same motion on a tilted, shifted ground gives the same figures.
    R = Rotation.from_rotvec([0.3, 0.2, -0.4]).as_matrix()
    moved = joints @ R.T + np.array([1.0, -2.0, 3.0])
    normal = np.tile(R @ [0.0, 1.0, 0.0], (len(joints), 1))
    offset = np.full(len(joints), -normal[0] @ np.array([1.0, -2.0, 3.0]))
    h = track_plausibility(moved, 30.0, 2.0 * normal, 2.0 * offset)  # unnormalised planes are fine
    for key in f:
        if f[key] is not None:
            assert h[key] == pytest.approx(f[key], abs=1e-9), key
    with pytest.raises(ValueError, match="shape"):
        track_plausibility(joints[:, :5], 30.0)


def test_motion_capture_walk_is_plausible():
    model = default_body_model()
    clip = next(c for c in load_clips() if "131" in c.info["name"])
    walk = slice(140, 200)  # CMU 131_01: the walking part
    joints = model.joints(clip.pose()[walk], clip.betas, clip.transl[walk])
    f = track_plausibility(joints, clip.fps)
    assert 0.9 < f["mean_speed_mps"] < 1.7
    assert f["slow_foot_speed_mps"] < 0.16  # 0.133: joint noise of the retargeting, heel-to-toe roll
    assert f["penetration_m"] < 0.05 and f["path_ratio"] < 1.2


def test_results_arrays_take_the_longest_valid_run():
    joints = _walker()
    P, T = 2, 100
    arrays = {"fps": np.float64(30.0), "track_ids": np.array([3, 4]), "valid": np.zeros((P, T), bool),
              "world_joints": np.full((P, T, 24, 3), np.nan), "ground_normal": np.full((P, T, 3), np.nan),
              "ground_offset": np.full((P, T), np.nan)}
    arrays["valid"][0, 5:95] = True
    arrays["world_joints"][0, 5:95] = joints
    arrays["valid"][1, 10] = True
    out = results_plausibility(arrays)
    assert out[1] is None and out[0]["frames"] == 90
    assert out[0]["mean_speed_mps"] == pytest.approx(track_plausibility(joints, 30.0)["mean_speed_mps"])


def _gait(model, strides_per_s, speed=1.2, seconds=5.0, fps=30.0, phase=0.4):
    """The procedural walker of m3c.eval.scenes (hips swinging +-0.45 rad, knees bending in the forward swing) at
    a known stride frequency, gliding along +z (the way the body faces) at `speed`."""
    from m3c.eval.scenes import walking_pose

    t = np.arange(round(seconds * fps)) / fps
    pose = np.zeros((len(t), 24, 3))
    pose[:, 1:] = walking_pose(2 * np.pi * strides_per_s * t + phase)
    transl = np.zeros((len(t), 3))
    transl[:, 2] = speed * t
    return model.joints(pose, np.zeros(model.num_betas), transl)


def _leg_length(model) -> float:
    rest = model.joints(np.zeros((1, 24, 3)), np.zeros(model.num_betas), np.zeros((1, 3)))[0]
    return float(np.linalg.norm(rest[1] - rest[4]) + np.linalg.norm(rest[4] - rest[7]))


@pytest.mark.parametrize("strides", [0.45, 0.9, 1.4])  # a slow-motion walk, a walk, a run's rate
def test_gait_recovers_a_known_step_rate(strides):
    model = default_body_model()
    joints = _gait(model, strides)
    f = track_plausibility(joints, 30.0)
    assert f["mean_speed_mps"] == pytest.approx(1.2, rel=1e-3)
    assert f["step_rate_spm"] == pytest.approx(120 * strides, rel=0.01)
    assert f["step_length_m"] == pytest.approx(1.2 / (2 * strides), rel=0.01)
    assert f["step_length_legs"] == pytest.approx(f["step_length_m"] / _leg_length(model), rel=0.01)
    # Noisy joints (2 cm), on a tilted, shifted ground, at another frame rate: the same gait.
    rng = np.random.default_rng(3)
    R = Rotation.from_rotvec([0.2, -0.5, 0.1]).as_matrix()
    fps = 25.0
    noisy = _gait(model, strides, fps=fps) @ R.T + [1.0, 2.0, -3.0] + rng.normal(0, 0.02, (125, 24, 3))
    normal = np.tile(R @ [0.0, 1.0, 0.0], (125, 1))
    offset = -normal @ np.array([1.0, 2.0, -3.0])
    g = track_plausibility(noisy, fps, normal, offset)
    assert g["step_rate_spm"] == pytest.approx(120 * strides, rel=0.03)


def test_gait_absent_where_the_feet_do_not_alternate():
    model = default_body_model()
    walk = _gait(model, 0.9)
    standing = np.repeat(walk[:1], len(walk), axis=0)
    assert track_plausibility(standing, 30.0)["step_rate_spm"] is None
    # Both feet together (a hop): the left ankle never leads the right.
    hop = walk.copy()
    hop[:, [8, 11]] = hop[:, [7, 10]] + (walk[0, 8] - walk[0, 7])
    assert track_plausibility(hop, 30.0)["step_length_m"] is None
    # Stepping in place while the whole body sways back and forth (a standing person's fit, its depth swinging): the
    # feet alternate and the pelvis moves, but the body goes nowhere.
    t = np.arange(len(walk)) / 30.0
    in_place = _gait(model, 0.9, speed=0.0) + (0.3 * np.sin(2 * np.pi * 0.3 * t))[:, None, None] * [0, 0, 1]
    figures = track_plausibility(in_place, 30.0)
    assert figures["mean_speed_mps"] > 0.2 and figures["step_rate_spm"] is None
    # One stride only: too short to call a rate.
    assert track_plausibility(_gait(model, 0.45, seconds=2.0), 30.0)["step_rate_spm"] is None
    # Feet wandering without a rhythm under a standing body (random steps of 3 cm a frame): no gait.
    rng = np.random.default_rng(0)
    wander = standing.copy()
    for foot in ((7, 10), (8, 11)):
        wander[:, list(foot)] += np.cumsum(rng.normal(0, 0.03, (len(walk), 1, 3)), axis=0) * [1, 0, 1]
    assert track_plausibility(wander, 30.0)["step_rate_spm"] is None


def test_slow_motion_walk_is_flagged_and_real_time_restores_it():
    """A walk played 2x slow (a normal step, 0.67 m, at 54 steps a minute) gets m3c info's slow-motion hint; the
    same frames at the real rate (what --slow-motion 2 gives) double the step rate and the speed and keep the step."""
    from m3c.io.results import _slow_gait_hint

    model = default_body_model()
    slow = track_plausibility(_gait(model, 0.45, speed=0.6, seconds=6.0), 30.0)
    assert slow["step_rate_spm"] == pytest.approx(54, rel=0.01) and 0.6 < slow["step_length_legs"] < 1.1
    assert "--slow-motion" in _slow_gait_hint(slow)
    real = track_plausibility(_gait(model, 0.45, speed=0.6, seconds=6.0), 60.0)
    assert real["step_rate_spm"] == pytest.approx(2 * slow["step_rate_spm"], rel=1e-6)
    assert real["mean_speed_mps"] == pytest.approx(2 * slow["mean_speed_mps"], rel=1e-6)
    assert real["step_length_m"] == pytest.approx(slow["step_length_m"], rel=1e-6)
    assert _slow_gait_hint(real) == ""
    # A short shuffle at a slow rate (0.28 m steps) is a slow walk, not slow motion: no hint.
    shuffle = track_plausibility(_gait(model, 0.45, speed=0.25, seconds=6.0), 30.0)
    assert shuffle["step_length_legs"] < 0.6 and _slow_gait_hint(shuffle) == ""


def _knee_flex_reference(joints, hip, knee, ankle):
    """Knee flexion by the law of cosines on the three joints' distances (independent of leg_figures' vectors)."""
    a = np.linalg.norm(joints[:, hip] - joints[:, knee], axis=1)
    b = np.linalg.norm(joints[:, knee] - joints[:, ankle], axis=1)
    c = np.linalg.norm(joints[:, hip] - joints[:, ankle], axis=1)
    return 180.0 - np.degrees(np.arccos(np.clip((a * a + b * b - c * c) / (2 * a * b), -1, 1)))


def test_legs_of_a_walk_swap_every_step_and_bend_in_swing():
    model = default_body_model()
    strides = 0.9
    joints = _gait(model, strides, seconds=6.0)
    f = track_plausibility(joints, 30.0)
    # Two lead changes a stride, each foot leading half a stride (the first and last leads cut short).
    assert f["lead_changes"] in (round(2 * strides * 6.0) - 1, round(2 * strides * 6.0))
    assert f["longest_lead_s"] == pytest.approx(0.5 / strides, abs=0.1)
    for side, (hip, knee, ankle) in enumerate(((1, 4, 7), (2, 5, 8))):
        reference = _knee_flex_reference(joints, hip, knee, ankle)
        assert f["knee_flex_deg"][side] == pytest.approx(np.median(reference), abs=0.01)
        assert f["knee_bent_fraction"][side] == pytest.approx((reference > 45).mean(), abs=1e-9)
    assert f["surge_ratio"] == pytest.approx(1.0, abs=0.02)  # a steady glide


def test_legs_that_never_swap_and_a_knee_held_bent_are_reported():
    """The bundled walker before the limb re-solve: the left knee bent backwards most of the time, the left foot
    behind for the whole walk, the pelvis advancing in surges; m3c info says CHECK."""
    from m3c.io.results import _legs_line

    model = default_body_model()
    n, fps = 150, 30.0
    pose = np.zeros((n, 24, 3))
    pose[:, 4, 0] = 1.3  # the left knee bent 75 degrees, the foot behind
    t = np.arange(n) / fps
    transl = np.zeros((n, 3))
    transl[:, 2] = 1.2 * np.floor(t / 2.5) + 1.2 * np.clip((t % 2.5 - 2.0) / 0.5, 0, 1)  # still 2 s, then a surge
    joints = model.joints(pose, np.zeros(model.num_betas), transl)
    f = track_plausibility(joints, fps)
    assert f["knee_bent_fraction"] == [1.0, 0.0]
    assert f["knee_flex_deg"][0] == pytest.approx(np.median(_knee_flex_reference(joints, 1, 4, 7)), abs=0.01)
    assert f["knee_flex_deg"][0] > 70
    assert f["lead_changes"] == 0 and f["longest_lead_s"] == pytest.approx(n / fps)
    assert f["surge_ratio"] > 2.0
    line = _legs_line(f)
    assert "CHECK" in line and "knee bent over 45" in line and "leads for over 2 s" in line and "surges" in line
    walk = track_plausibility(_gait(model, 0.9, seconds=5.0), 30.0)
    assert "CHECK" not in _legs_line(walk)
