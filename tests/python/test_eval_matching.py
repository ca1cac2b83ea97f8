"""Track alignment (common frames) and Hungarian matching on mean PA-MPJPE, on constructed cases."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.eval.matching import JointTrack, common_frames, match_tracks, pa_mpjpe_cost
from m3c.eval.metrics import pa_mpjpe


def test_common_frames_trims_to_the_overlap():
    ia, ib = common_frames([3, 4, 5, 6, 7], [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(ia, [0, 1, 2])   # frames 3, 4, 5 of a
    np.testing.assert_array_equal(ib, [3, 4, 5])   # the same frames in b
    ia, ib = common_frames([0, 1], [5, 6])
    assert len(ia) == len(ib) == 0


def test_joint_track_validates():
    with pytest.raises(ValueError, match="strictly increasing"):
        JointTrack([0, 2, 1], np.zeros((3, 4, 3)))
    with pytest.raises(ValueError, match=r"\(n=2, J, 3\)"):
        JointTrack([0, 1], np.zeros((3, 4, 3)))


def people(rng, count, n=30, J=14):
    """Distinct poses per person: the pose matters, not the location (PA removes the location)."""
    return [rng.normal(size=(1, J, 3)) * 0.3 + 0.02 * rng.normal(size=(n, J, 3)) for _ in range(count)]


def test_cost_uses_only_common_frames(rng):
    gt_joints = people(rng, 1, n=20)[0]
    pred_joints = gt_joints[5:15].copy()
    pred_joints[:3] += 0.05 * rng.normal(size=pred_joints[:3].shape)
    gt = JointTrack(np.arange(20), gt_joints)
    pred = JointTrack(np.arange(5, 15), pred_joints)
    cost = pa_mpjpe_cost([gt], [pred])
    assert cost[0, 0] == pytest.approx(pa_mpjpe(pred_joints, gt_joints[5:15]).mean())
    assert pa_mpjpe_cost([gt], [pred], min_common_frames=11)[0, 0] == np.inf


def test_hungarian_finds_the_permutation_brute_force_finds(rng):
    gts = people(rng, 3)
    # Predictions: the three people in shuffled order (rotated and noisy, so PA matters), plus a false track.
    order = [2, 0, 1]
    preds = []
    for k in order:
        R = Rotation.random(random_state=int(k)).as_matrix()
        preds.append(gts[k] @ R.T + 5.0 + 0.03 * rng.normal(size=gts[k].shape))
    preds.append(people(rng, 1)[0])
    gt_tracks = [JointTrack(np.arange(30), g) for g in gts]
    pred_tracks = [JointTrack(np.arange(30), p) for p in preds]
    result = match_tracks(gt_tracks, pred_tracks)
    pairs = {(m.gt, m.pred) for m in result.matches}
    assert pairs == {(2, 0), (0, 1), (1, 2)}
    assert result.unmatched_pred == [3] and result.unmatched_gt == []
    # The total equals the brute-force minimum over all assignments.
    cost = result.cost
    brute = min(sum(cost[g, p] for g, p in zip(range(3), perm)) for perm in itertools.permutations(range(4), 3))
    assert sum(m.pa_mpjpe for m in result.matches) == pytest.approx(brute)


def test_pairs_without_common_frames_are_never_matched(rng):
    g0, g1 = people(rng, 2)
    gt_tracks = [JointTrack(np.arange(30), g0), JointTrack(np.arange(100, 130), g1)]
    # The only prediction overlaps ground truth 1 in time, although its pose is person 0's.
    pred_tracks = [JointTrack(np.arange(100, 130), g0)]
    result = match_tracks(gt_tracks, pred_tracks)
    assert [(m.gt, m.pred) for m in result.matches] == [(1, 0)]
    assert result.unmatched_gt == [0]
    assert result.matches[0].num_frames == 30


def test_no_predictions_leaves_every_ground_truth_unmatched(rng):
    gt_tracks = [JointTrack(np.arange(5), g) for g in people(rng, 2, n=5)]
    result = match_tracks(gt_tracks, [])
    assert result.matches == [] and result.unmatched_gt == [0, 1]
