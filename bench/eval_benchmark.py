"""The ground-truth accuracy benchmark (m3c.eval.benchmark) with its tables, plus the optimizer's cost as a
ratio against the Local method (placing and evaluating the same bodies) measured in the same run.

Sequences: retargeted CMU motion capture (shipped), one to three people, virtual cameras (walking handheld,
panning, orbiting, static), simulated keypoints / camera-local bodies / visual odometry with realistic errors.
All figures in mm unless the header says otherwise. The default (2 sequences x 120 frames) takes a few minutes
on 2 cores; --sequences 8 --frames 200 covers every camera motion twice.

    PYTHONPATH=python python3 bench/eval_benchmark.py [--sequences 2] [--frames 120] [--seed 0]
        [--mocap ../shared/data/mocap/bandai_namco] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys

from m3c.body import default_body_model
from m3c.eval.benchmark import BenchmarkConfig, retarget_folder, run_benchmark, shipped_clip_paths
from m3c.io.atomic import atomic_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=2)
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-people", type=int, default=3)
    parser.add_argument("--mocap", action="append", default=[], help="a BVH folder to add (retargeted, cached)")
    parser.add_argument("--json", help="write the summary here")
    args = parser.parse_args()

    model = default_body_model()
    log = (lambda text: print(text, file=sys.stderr, flush=True))
    clips = list(shipped_clip_paths())
    for folder in args.mocap:
        clips += retarget_folder(model, folder, log=log)
    config = BenchmarkConfig(num_sequences=args.sequences, num_frames=args.frames, seed=args.seed,
                             max_people=args.max_people, clip_paths=tuple(str(c) for c in clips))
    report = run_benchmark(model, config, log)
    print(report.tables())
    person_frames = sum(s.num_people for s in report.sequences) * config.num_frames
    local = sum(s.seconds["Local"] for s in report.sequences)
    opt = sum(s.seconds["Global Opt"] for s in report.sequences)
    print(f"\nGlobal Opt: {opt:.1f} s for {person_frames} person-frames "
          f"({1000 * opt / person_frames:.1f} ms each), {opt / local:.1f}x the Local method's time (posing and "
          f"evaluating the same bodies, {local:.1f} s)")
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(report.summary(), indent=1))


if __name__ == "__main__":
    main()
