"""The gait figures (m3c.eval.plausibility: steps a minute, step length, step in leg lengths) and the mean speed
of each person of finished video-benchmark runs, the truth's beside Global Opt's (or the lift's), for every matched
person seen for two seconds or more; then the share of people with a gait and the step rate's error.

    PYTHONPATH=python python3 bench/video_benchmark_gait.py OUT [OUT ...] [--method "Global Opt"|Lift]
    (OUT: the --out folder of `m3c eval video-benchmark`, holding videos/ and runs/)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from m3c.body import default_body_model
from m3c.eval.evaluate import evaluate_sequence
from m3c.eval.matching import common_frames
from m3c.eval.plausibility import track_plausibility
from m3c.eval.video_benchmark import PELVIS, predicted_tracks, truth_tracks

FIELDS = (("mean_speed_mps", "m/s", ".2f"), ("step_rate_spm", "steps", ".0f"), ("step_length_m", "step m", ".2f"),
          ("step_length_legs", "legs", ".2f"))


def cells(figures: dict) -> str:
    return "".join(f"{'-' if figures[key] is None else format(figures[key], fmt):>8}" for key, _, fmt in FIELDS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outs", nargs="+", type=Path)
    parser.add_argument("--method", default="Global Opt", choices=("Global Opt", "Lift"))
    args = parser.parse_args()
    model = default_body_model()
    names = "".join(f"{label:>8}" for _, label, _ in FIELDS)
    print(f"{'sequence / person':<40}{'truth:':<7}{names}   {args.method}:{names}")
    pairs = []
    for out in args.outs:
        for run in sorted((out / "runs").iterdir()):
            truth_file, results_file = out / "videos" / run.name / "truth.npz", run / "results.npz"
            if not (truth_file.is_file() and results_file.is_file()):
                continue
            with np.load(truth_file) as f:
                truth = dict(f)
            with np.load(results_file) as f:
                arrays = dict(f)
            fps = float(truth["fps"])
            gt, pred = truth_tracks(model, truth), predicted_tracks(model, arrays, args.method)
            for match in evaluate_sequence(gt, pred, fps, pelvis=PELVIS, name=run.name).matching.matches:
                ig, ip = common_frames(gt[match.gt].frames, pred[match.pred].frames)
                if len(ig) < 2 * fps:
                    continue
                true = track_plausibility(gt[match.gt].joints_world[ig], fps)
                found = track_plausibility(pred[match.pred].joints_world[ip], fps)
                pairs.append((true, found))
                print(f"{out.name + '/' + run.name[:24] + f' p{match.gt}':<40}{'':<7}{cells(true)}   "
                      f"{'':<{len(args.method) + 1}}{cells(found)}")
    both = [(t, f) for t, f in pairs if t["step_rate_spm"] is not None and f["step_rate_spm"] is not None]
    errors = np.array([100 * abs(f["step_rate_spm"] / t["step_rate_spm"] - 1) for t, f in both])
    print(f"\npeople {len(pairs)}: a gait in the truth {sum(t['step_rate_spm'] is not None for t, _ in pairs)}, "
          f"in {args.method} {sum(f['step_rate_spm'] is not None for _, f in pairs)}, both {len(both)}"
          + (f"; step rate off by {np.median(errors):.1f}% (median), {errors.max():.1f}% at most" if len(both) else ""))


if __name__ == "__main__":
    main()
