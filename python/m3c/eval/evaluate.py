"""Evaluating predicted tracks against ground-truth tracks of one sequence, and aggregating over sequences.

Per sequence: predictions are matched to ground-truth people (Hungarian on mean PA-MPJPE, thesis 5.2.3), every
matched pair is trimmed to its common frames (5.2.2), and the metrics are computed per frame. Aggregates are
means over all frames of all matched people of all sequences (as WHAM and GVHMR average), so long tracks weigh
more than short ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from m3c.eval import metrics as M
from m3c.eval.matching import Matching, common_frames, match_tracks
from m3c.eval.tracks import EvalTrack

# Metric key -> (column title, unit, scale applied when printing).
METRICS = {
    "pa_mpjpe": ("PA-MPJPE", "mm", 1.0),
    "mpjpe": ("MPJPE", "mm", 1.0),
    "pve": ("PVE", "mm", 1.0),
    "accel": ("Accel", "m/s^2", 1.0),
    "wa_mpjpe": ("WA-MPJPE100", "mm", 1.0),
    "w_mpjpe": ("W-MPJPE100", "mm", 1.0),
    "rte": ("RTE", "%", 1.0),
    "jitter": ("Jitter", "10m/s^3", 0.1),
    "foot_sliding": ("FS", "mm", 1.0),
}
CAMERA_FRAME_METRICS = ("pa_mpjpe", "mpjpe", "pve", "accel")
WORLD_METRICS = ("wa_mpjpe", "w_mpjpe", "rte", "jitter", "foot_sliding")


@dataclass
class SequenceResult:
    name: str
    num_gt: int
    matching: Matching
    values: dict = field(default_factory=dict)    # metric -> list of per-frame arrays
    notes: list = field(default_factory=list)     # metrics skipped and why
    extra: dict = field(default_factory=dict)     # per-sequence scalars (camera ATE, scale error, ...)
    joint_errors: list = field(default_factory=list)  # per matched person: (frames, J) PA-aligned errors, mm
    joint_depths: list = field(default_factory=list)  # and the true joints' camera depths (frames, J), m

    def frames(self, metric: str) -> np.ndarray:
        parts = self.values.get(metric, [])
        return np.concatenate(parts) if parts else np.zeros(0)

    def mean(self, metric: str) -> float | None:
        v = self.frames(metric)
        return float(v.mean()) if len(v) else None


def _runs(frames: np.ndarray) -> list[slice]:
    """Slices of consecutive frame ids (finite differences must not straddle a gap)."""
    breaks = np.flatnonzero(np.diff(frames) != 1) + 1
    starts = np.concatenate([[0], breaks])
    stops = np.concatenate([breaks, [len(frames)]])
    return [slice(a, b) for a, b in zip(starts, stops)]


def evaluate_sequence(gt_tracks: list[EvalTrack], pred_tracks: list[EvalTrack], fps: float, pelvis=(1, 2),
                      name: str = "", world: bool = True, segment: int = M.SEGMENT_FRAMES,
                      min_common_frames: int = 1) -> SequenceResult:
    """Matches predictions to the ground truth and computes every metric both sides allow, per frame.

    pelvis: indices of the evaluation joints averaged into the pelvis (SMPL 24 joints: the hips (1, 2);
    the 14 H36M evaluation joints: (2, 3)). world: also the world-frame metrics (needs joints_world)."""
    matching = match_tracks([t.joint_track() for t in gt_tracks], [t.joint_track() for t in pred_tracks],
                            min_common_frames)
    result = SequenceResult(name, len(gt_tracks), matching, {k: [] for k in METRICS})
    for match in matching.matches:
        ig, ip = common_frames(gt_tracks[match.gt].frames, pred_tracks[match.pred].frames)
        gt = gt_tracks[match.gt].take(ig)
        pred = pred_tracks[match.pred].take(ip)
        add = (lambda key, v: result.values[key].append(np.asarray(v, dtype=np.float64)))
        add("pa_mpjpe", M.pa_mpjpe(pred.joints_cam, gt.joints_cam))
        result.joint_errors.append(M.pa_joint_errors(pred.joints_cam, gt.joints_cam))
        result.joint_depths.append(np.asarray(gt.joints_cam, dtype=np.float64)[..., 2])
        add("mpjpe", M.mpjpe(pred.joints_cam, gt.joints_cam, pelvis))
        if pred.vertices_cam is not None and gt.vertices_cam is not None:
            if pred.vertices_cam.shape[1] == gt.vertices_cam.shape[1]:
                add("pve", M.pve(pred.vertices_cam, gt.vertices_cam, pred.joints_cam, gt.joints_cam, pelvis))
            else:
                result.notes.append("PVE skipped: prediction and ground truth meshes differ in vertex count")
        runs = _runs(gt.frames)
        for run in runs:
            if run.stop - run.start >= 3:
                add("accel", M.accel_error(pred.joints_cam[run], gt.joints_cam[run], fps, pelvis))
        if not world or pred.joints_world is None or gt.joints_world is None:
            continue
        add("wa_mpjpe", M.wa_mpjpe(pred.joints_world, gt.joints_world, segment))
        add("w_mpjpe", M.w_mpjpe(pred.joints_world, gt.joints_world, segment))
        root_gt = M.pelvis_of(gt.joints_world, pelvis)
        root_pred = M.pelvis_of(pred.joints_world, pelvis)
        try:
            add("rte", M.rte(root_pred, root_gt))
        except ValueError as err:
            result.notes.append(f"RTE skipped for ground-truth person {match.gt}: {err}")
        for run in runs:
            if run.stop - run.start >= 4:
                add("jitter", M.jitter(pred.joints_world[run], fps))
        if pred.feet_world is not None and gt.feet_world is not None:
            for run in runs:
                if run.stop - run.start >= 2:
                    add("foot_sliding", M.foot_sliding(pred.feet_world[run], gt.feet_world[run]))
    return result


def aggregate(results: list[SequenceResult]) -> dict[str, float | None]:
    """Per-frame means over all sequences: metric -> value (None where no sequence produced it)."""
    out = {}
    for key in METRICS:
        parts = [r.frames(key) for r in results]
        values = np.concatenate(parts) if parts else np.zeros(0)
        out[key] = float(values.mean()) if len(values) else None
    return out


# SMPL's arms (shoulder, elbow, wrist) on either side: a far arm folded the wrong way shows as elbow and wrist
# errors much larger than the shoulder's.
SMPL_ARMS = ((16, 18, 20), (17, 19, 21))


def arm_errors(results: list[SequenceResult], arms=SMPL_ARMS) -> dict | None:
    """PA-aligned per-joint errors (mm) of the shoulders, elbows and wrists over all matched frames of the
    results, on both sides and on the far side (the arm whose true shoulder is further from the camera), and the
    ratio of the worse of elbow and wrist to the shoulder. None without frames."""
    errors = [e for r in results for e in r.joint_errors]
    depths = [d for r in results for d in r.joint_depths]
    if not errors or not sum(len(e) for e in errors):
        return None
    e, d = np.concatenate(errors), np.concatenate(depths)
    sides = np.asarray(arms)  # (2, 3)
    far = (d[:, sides[1, 0]] > d[:, sides[0, 0]]).astype(int)  # 1: the second side's shoulder is further
    far_e = e[np.arange(len(e))[:, None], sides[far]]  # (frames, 3)
    both = (e[:, sides[0]] + e[:, sides[1]]) / 2
    out = {"frames": int(len(e))}
    for name, values in (("", both), ("far_", far_e)):
        shoulder, elbow, wrist = (float(v) for v in values.mean(0))
        out.update({f"{name}shoulder_mm": shoulder, f"{name}elbow_mm": elbow, f"{name}wrist_mm": wrist,
                    f"{name}ratio": max(elbow, wrist) / shoulder if shoulder > 0 else None})
    return out


def format_value(key: str, value: float | None, width: int = 9, digits: int = 1) -> str:
    if value is None:
        return "-".rjust(width)
    return f"{value * METRICS[key][2]:{width}.{digits}f}"


def format_method_table(rows: dict[str, dict | str], columns=tuple(METRICS)) -> str:
    """The thesis's Table 5.1 layout: one row per method, one column per metric (units in the header).
    A row given as a string is printed as a note in place of its numbers (e.g. a method that could not
    run)."""
    name_w = max([len("Method")] + [len(k) for k in rows]) + 2
    col_w = max(9, *(len(METRICS[c][0]) + 1 for c in columns))
    head1 = "Method".ljust(name_w) + "".join(METRICS[c][0].rjust(col_w) for c in columns)
    head2 = "".ljust(name_w) + "".join(f"({METRICS[c][1]})".rjust(col_w) for c in columns)
    lines = [head1, head2, "-" * len(head1)]
    for method, values in rows.items():
        if isinstance(values, str):
            lines.append(method.ljust(name_w) + "  " + values)
        else:
            lines.append(method.ljust(name_w) + "".join(format_value(c, values.get(c), col_w) for c in columns))
    return "\n".join(lines)
