"""Track alignment and bipartite matching of predicted to ground-truth tracks (thesis 5.2.2-5.2.3).

Alignment: a predicted and a ground-truth track are compared on the frames both contain (the ground truth is
usually longer; frames before the prediction's first and after its last are dropped).
Matching: the tracker's ids are not the dataset's, so every (ground truth, prediction) pair is scored by its
mean PA-MPJPE over the common frames and the Hungarian (Munkres) algorithm picks the one-to-one assignment
with the least total, i.e. the least average PA-MPJPE over the matched ground-truth tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from m3c.eval.metrics import pa_mpjpe


@dataclass
class JointTrack:
    """One person's joints over frames: frames (n,) increasing frame ids, joints (n, J, 3) metres."""

    frames: np.ndarray
    joints: np.ndarray

    def __post_init__(self):
        self.frames = np.asarray(self.frames, dtype=np.int64).reshape(-1)
        self.joints = np.asarray(self.joints, dtype=np.float64)
        if self.joints.ndim != 3 or self.joints.shape[-1] != 3 or len(self.joints) != len(self.frames):
            raise ValueError(f"joints must have shape (n={len(self.frames)}, J, 3) to match frames, got "
                             f"{self.joints.shape}")
        if np.any(np.diff(self.frames) <= 0):
            raise ValueError("frames must be strictly increasing frame ids")


def common_frames(frames_a, frames_b) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a, into b) of the frame ids both tracks contain, in increasing frame order."""
    a = np.asarray(frames_a, dtype=np.int64).reshape(-1)
    b = np.asarray(frames_b, dtype=np.int64).reshape(-1)
    _, ia, ib = np.intersect1d(a, b, assume_unique=True, return_indices=True)
    return ia, ib


@dataclass
class Match:
    gt: int            # index of the ground-truth track
    pred: int          # index of the predicted track
    pa_mpjpe: float    # mean PA-MPJPE over the common frames, mm
    num_frames: int    # common frames


@dataclass
class Matching:
    matches: list[Match]
    unmatched_gt: list[int]     # ground-truth tracks with no prediction (missed people)
    unmatched_pred: list[int]   # predictions assigned to no ground truth (false or duplicate tracks)
    cost: np.ndarray            # (G, P) mean PA-MPJPE per pair, inf where a pair shares too few frames


def pa_mpjpe_cost(gt_tracks: list[JointTrack], pred_tracks: list[JointTrack],
                  min_common_frames: int = 1) -> np.ndarray:
    """(G, P) mean PA-MPJPE (mm) of every pair over its common frames; inf where fewer than
    min_common_frames."""
    cost = np.full((len(gt_tracks), len(pred_tracks)), np.inf)
    for g, gt in enumerate(gt_tracks):
        for p, pred in enumerate(pred_tracks):
            if gt.joints.shape[1] != pred.joints.shape[1]:
                raise ValueError(f"ground-truth track {g} has {gt.joints.shape[1]} joints, prediction {p} has "
                                 f"{pred.joints.shape[1]}: evaluate both with the same joint regressor")
            ig, ip = common_frames(gt.frames, pred.frames)
            if len(ig) >= max(1, min_common_frames):
                cost[g, p] = float(pa_mpjpe(pred.joints[ip], gt.joints[ig]).mean())
    return cost


def match_tracks(gt_tracks: list[JointTrack], pred_tracks: list[JointTrack],
                 min_common_frames: int = 1) -> Matching:
    """One-to-one assignment of predictions to ground-truth tracks minimising the summed mean PA-MPJPE."""
    cost = pa_mpjpe_cost(gt_tracks, pred_tracks, min_common_frames)
    matches = []
    if cost.size and np.isfinite(cost).any():
        # Pairs that share no frames must never be chosen: a cost above any feasible total keeps them out.
        big = 1.0 + np.nansum(np.where(np.isfinite(cost), cost, 0.0)) * 2.0
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, big))
        for g, p in zip(rows, cols):
            if np.isfinite(cost[g, p]):
                n = len(common_frames(gt_tracks[g].frames, pred_tracks[p].frames)[0])
                matches.append(Match(int(g), int(p), float(cost[g, p]), n))
    matched_gt = {m.gt for m in matches}
    matched_pred = {m.pred for m in matches}
    return Matching(matches, [g for g in range(len(gt_tracks)) if g not in matched_gt],
                    [p for p in range(len(pred_tracks)) if p not in matched_pred], cost)
