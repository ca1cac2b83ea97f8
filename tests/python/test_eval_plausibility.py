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
