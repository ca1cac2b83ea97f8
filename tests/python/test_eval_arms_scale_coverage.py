"""The benchmark's far-arm figures (per-joint errors of the shoulders, elbows and wrists after PA alignment, the
far side chosen by the true shoulders' depth) and each scale source's 2-sigma coverage, against numbers
computed by hand."""

import numpy as np
import pytest

from m3c.eval import metrics as M
from m3c.eval.evaluate import SequenceResult, arm_errors
from m3c.eval.matching import Matching
from m3c.eval.video_benchmark import source_coverage
from m3c.vo.scale import PERSON_SIZE_SIGMA


def test_pa_joint_errors_average_to_pa_mpjpe(rng):
    gt = rng.normal(size=(5, 24, 3))
    pred = gt + 0.05 * rng.normal(size=gt.shape)
    per_joint = M.pa_joint_errors(pred, gt)
    assert per_joint.shape == (5, 24)
    np.testing.assert_allclose(per_joint.mean(-1), M.pa_mpjpe(pred, gt), rtol=1e-12)


def test_arm_errors_pick_the_far_side_by_the_true_depth():
    errors = np.zeros((2, 24))
    errors[:, [16, 18, 20]] = [10.0, 20.0, 30.0]     # left shoulder, elbow, wrist
    errors[:, [17, 19, 21]] = [10.0, 40.0, 80.0]     # right
    depths = np.full((2, 24), 3.0)
    depths[0, 16], depths[0, 17] = 3.2, 3.0          # frame 0: the left arm is the far one
    depths[1, 16], depths[1, 17] = 3.0, 3.3          # frame 1: the right
    result = SequenceResult("s", 1, Matching([], [], [], np.zeros((0, 0))), joint_errors=[errors], joint_depths=[depths])
    arms = arm_errors([result])
    assert arms["frames"] == 2
    assert (arms["shoulder_mm"], arms["elbow_mm"], arms["wrist_mm"]) == (10.0, 30.0, 55.0)
    assert arms["ratio"] == pytest.approx(5.5)
    assert (arms["far_elbow_mm"], arms["far_wrist_mm"]) == (30.0, 55.0)  # (20 + 40) / 2, (30 + 80) / 2
    assert arm_errors([SequenceResult("empty", 0, Matching([], [], [], np.zeros((0, 0))))]) is None


def test_source_coverage_against_the_lifts_scale_error():
    # The lift carried the fused 2.0 m per unit and came out 25% large: the truth is 1.6.
    scale = {"value": 2.0, "observations": [
        {"source": "ground", "value": 1.7, "sigma": 0.02, "person_size": False, "detail": {}},
        {"source": "feet", "value": 2.4, "sigma": 0.1, "person_size": True, "detail": {"set_aside": True}},
        {"source": "gait", "value": None, "sigma": None, "reason": "no steady gait"}]}
    rows = source_coverage(scale, 25.0)
    assert [r["source"] for r in rows] == ["ground", "feet"]
    ground, feet = rows
    assert ground["error_pct"] == pytest.approx(100 * (1.7 / 1.6 - 1))
    assert not ground["covered"]                       # log(1.7/1.6) = 0.061 > 2 x 0.02
    assert feet["sigma"] == pytest.approx(np.hypot(0.1, PERSON_SIZE_SIGMA))
    assert feet["covered"] == (abs(np.log(2.4 / 1.6)) <= 2 * np.hypot(0.1, PERSON_SIZE_SIGMA))
    assert feet["set_aside"] and not ground["set_aside"]
    assert source_coverage(scale, None) == [] and source_coverage(scale, -100.0) == []
