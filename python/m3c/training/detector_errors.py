"""How M3C's 2D detector errs, measured on rendered video-benchmark sequences against their projected truth;
the model the regressor's virtual cameras corrupt their projected keypoints with
(m3c.training.virtual_camera).

For every track of a run (the `local_tracks` node of its cache: keypoints (n, 17, 3) with confidence, square
box (n, 4) x0 y0 x1 y1) the person of the truth it follows is the one whose projected COCO-17 keypoints lie
nearest on average. Then, over the frames where that person's keypoint is inside the image:
    error_quantiles   per joint, the quantiles (QUANTILES) of |k_det - k_true| / box side, for the keypoints
                      the detector reports (confidence >= MASK_CONFIDENCE, WHAM's threshold)
    error_lag1        per joint, the lag-1 autocorrelation of the error vectors (how slowly they drift)
    missing_rate      per joint, the share reported below MASK_CONFIDENCE (self-occlusion, blur, misses)
    box_centre        mean, std and lag-1 autocorrelation of (c_det - c_true) / side, c_true the centre of the
                      true keypoints' bounding box
    box_log_side      the same of log(side_det / side_true), side_true the longer edge of that bounding box
`python -m m3c.training.detector_errors VIDEOS RUNS` measures and writes DETECTOR_ERRORS_PATH.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from m3c.models.wham import MASK_CONFIDENCE

DETECTOR_ERRORS_PATH = Path(__file__).with_name("detector_errors.json")
QUANTILES = tuple(np.round(np.linspace(0.0, 1.0, 21), 2).tolist())


def _tracks(run_dir: Path) -> list[dict]:
    """The tracks of a run's local_tracks node: dicts with first_frame, keypoints (n, 17, 3), box (n, 4)."""
    out = []
    for node in sorted((run_dir / "cache" / "local_tracks").iterdir()):
        outputs = json.loads((node / "outputs.json").read_text())
        with np.load(node / "arrays.npz") as arrays:
            for track in outputs["tracks"]["tracks"]:
                out.append({"first_frame": int(track["first_frame"]),
                            "keypoints": arrays[track["keypoints"]["__array__"]].astype(np.float64),
                            "box": arrays[track["box"]["__array__"]].astype(np.float64)})
    return out


def _lag1(x: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """(sum of x[t] . x[t+1], sum of |x[t]|^2) over consecutive valid frames, x (n, d) centred."""
    pair = valid[1:] & valid[:-1]
    return float((x[1:][pair] * x[:-1][pair]).sum()), float((x[:-1][pair] ** 2).sum())


def measure(videos: Path, runs: Path) -> dict:
    """The error model of the runs under `runs` (runs/<seq>/cache) against the truth under `videos`
    (videos/<seq>/truth.npz)."""
    errors = [[] for _ in range(17)]
    lag = np.zeros((17, 2))
    reported = np.zeros(17)
    seen = np.zeros(17)
    centre, log_side, box_lag = [], [], np.zeros((2, 2))
    sequences = []
    for run_dir in sorted(p for p in Path(runs).iterdir() if (p / "cache" / "local_tracks").is_dir()):
        truth_file = Path(videos) / run_dir.name / "truth.npz"
        if not truth_file.is_file():
            continue
        with np.load(truth_file) as truth:
            true_kp = truth["keypoints_2d"].astype(np.float64)          # (P, T, 17, 2)
            inside = truth["keypoints_in_image"].astype(bool)            # (P, T, 17)
        sequences.append(run_dir.name)
        for track in _tracks(run_dir):
            n = len(track["keypoints"])
            frames = track["first_frame"] + np.arange(n)
            kp, box = track["keypoints"], track["box"]
            gap = [np.nanmean(np.where(inside[p, frames][..., None], np.abs(kp[..., :2] - true_kp[p, frames]),
                                       np.nan)) for p in range(len(true_kp))]
            p = int(np.nanargmin(gap))
            truth_kp, truth_in = true_kp[p, frames], inside[p, frames]
            side = box[:, 2] - box[:, 0]
            ok = truth_in & (kp[..., 2] >= MASK_CONFIDENCE)
            seen += truth_in.sum(0)
            reported += ok.sum(0)
            error = (kp[..., :2] - truth_kp) / side[:, None, None]
            for j in range(17):
                if not ok[:, j].any():
                    continue
                errors[j].append(np.linalg.norm(error[ok[:, j], j], axis=-1))
                e = error[:, j] - error[ok[:, j], j].mean(0)
                lag[j] += _lag1(e, ok[:, j])
            any_in = truth_in.sum(1) >= 6
            lo = np.where(truth_in[..., None], truth_kp, np.inf).min(1)
            hi = np.where(truth_in[..., None], truth_kp, -np.inf).max(1)
            true_side = (hi - lo).max(1)
            c = ((box[:, :2] + box[:, 2:]) / 2 - (lo + hi) / 2) / side[:, None]
            s = np.log(side / np.maximum(true_side, 1.0))
            centre.append(c[any_in])
            log_side.append(s[any_in])
            box_lag[0] += _lag1(c - c[any_in].mean(0), any_in)
            box_lag[1] += _lag1((s - s[any_in].mean())[:, None], any_in)
    if not sequences:
        raise FileNotFoundError(f"no run under {runs} with a local_tracks cache and a truth under {videos}")
    all_errors = [np.concatenate(e) for e in errors]
    centre, log_side = np.concatenate(centre), np.concatenate(log_side)
    return {
        "description": "M3C's 2D keypoint detector's errors on the rendered video benchmark (see "
                       "m3c/training/detector_errors.py for how they are measured)",
        "sequences": sequences, "frames_measured": int(seen.max()),
        "mask_confidence": MASK_CONFIDENCE, "quantiles": list(QUANTILES),
        "error_quantiles": [np.quantile(e, QUANTILES).round(5).tolist() for e in all_errors],
        "error_lag1": [round(float(a / max(b, 1e-12)), 4) for a, b in lag],
        "missing_rate": (1.0 - reported / np.maximum(seen, 1)).round(4).tolist(),
        "box_centre": {"mean": centre.mean(0).round(5).tolist(), "std": centre.std(0).round(5).tolist(),
                       "lag1": round(box_lag[0, 0] / max(box_lag[0, 1], 1e-12), 4)},
        "box_log_side": {"mean": round(float(log_side.mean()), 5), "std": round(float(log_side.std()), 5),
                         "lag1": round(box_lag[1, 0] / max(box_lag[1, 1], 1e-12), 4)},
    }


def load_detector_errors(path: str | Path | None = None) -> dict:
    """The stored error model (DETECTOR_ERRORS_PATH by default)."""
    return json.loads(Path(path or DETECTOR_ERRORS_PATH).read_text())


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m m3c.training.detector_errors VIDEOS RUNS", file=sys.stderr)
        return 2
    model = measure(Path(argv[0]), Path(argv[1]))
    DETECTOR_ERRORS_PATH.write_text(json.dumps(model, indent=1) + "\n")
    print(f"wrote {DETECTOR_ERRORS_PATH}: {len(model['sequences'])} sequences, median error "
          f"{np.median([q[10] for q in model['error_quantiles']]):.3f} box sides, missing "
          f"{np.mean(model['missing_rate']):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
