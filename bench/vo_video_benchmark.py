"""The patch odometry on the video benchmark's rendered sequences against their true cameras: each patch seed's run
alone and the best fit of several (m3c.vo keeps the run of least keyframe_fit_rms of VOConfig.hypotheses runs).
The odometry sees what it sees in the pipeline: the people masks of the benchmark run's cached perception and the
intrinsics its run estimated (results.json), so run the benchmark first.

    python3 -m m3c eval video-benchmark --seed 0 --out OUT        # renders and runs (cached under OUT)
    PYTHONPATH=python python3 bench/vo_video_benchmark.py OUT [OUT ...] [--seeds 3]

Per moving-camera sequence (static cameras are skipped): the largest rotation error over its frames (degrees: the
rotation from the first frame against the truth's) and the ATE (% of the true path, Sim(3)-aligned; '-' for a
camera that only turns) of each seed's run alone and of the kept one, with the keyframe fit rms (px) of each.
Then per column: failures (rotation error over 5 degrees) and the time against one run, in this process.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.io.video import iter_frames
from m3c.nodes.records import people_mask, rows_by_frame
from m3c.pipeline.cache import Cache
from m3c.vo import VOConfig, path_length, relative_ate, run_vo

FAILURE_DEG = 5.0


def pipeline_inputs(run: Path):
    """(frames (T, H, W, 3) BGR, people masks (T, H, W), intrinsics (4,)) of a finished benchmark run."""
    records = {r["name"]: r["key"] for r in json.loads((run / "cache" / "last_run.json").read_text())["records"]}
    perception = Cache(run / "cache").load("perception", records["perception"])
    video = json.loads((run / "results.json").read_text())
    frames = np.stack([f for _, f in iter_frames(run.parent.parent / "videos" / run.name / "video.mp4")])
    height, width = frames.shape[1:3]
    rows = rows_by_frame(perception["detections"])
    masks = np.stack([people_mask(perception["masks"], rows.get(t, []), width, height) for t in range(len(frames))])
    return frames, masks, np.asarray(video["camera"]["intrinsics"], dtype=np.float64)


def errors(estimated: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(largest rotation error over the frames in degrees, ATE in % of the true path or nan without a path)."""
    relative = lambda w: np.einsum("ji,tjk->tik", w[0, :3, :3], w[:, :3, :3])  # noqa: E731
    rotation = Rotation.from_matrix(np.einsum("tji,tjk->tik", relative(truth), relative(estimated)))
    path = path_length(truth[:, :3, 3])
    ate = 100.0 * relative_ate(estimated, truth) if path > 0.05 else math.nan
    return float(np.degrees(rotation.magnitude()).max()), ate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="+", type=Path, help="video benchmark output folders (--out of the benchmark)")
    parser.add_argument("--seeds", type=int, default=VOConfig().hypotheses, help="runs the best fit is kept of")
    args = parser.parse_args()
    columns = [f"seed {k}" for k in range(args.seeds)] + ["kept"]
    failures, seconds = dict.fromkeys(columns, 0), dict.fromkeys(columns, 0.0)
    count = 0
    print(f"{'sequence':<40}" + "".join(f"{c:>24}" for c in columns))
    for out in args.out:
        for run in sorted((out / "runs").glob("*")):
            truth_file = out / "videos" / run.name / "truth.npz"
            if "static" in run.name or not (run / "results.json").is_file() or not truth_file.is_file():
                continue
            truth = np.load(truth_file)["world_from_cam"]
            frames, masks, intrinsics = pipeline_inputs(run)
            cells = []
            for column in columns:
                config = VOConfig(hypotheses=args.seeds) if column == "kept" else \
                    VOConfig(hypotheses=1, seed=int(column.split()[1]))
                start = time.perf_counter()
                result = run_vo(frames, masks=masks, intrinsics=intrinsics, config=config, bgr=True)
                seconds[column] += time.perf_counter() - start
                rotation, ate = errors(result.world_from_cam, truth)
                failures[column] += rotation > FAILURE_DEG
                cells.append(f"{rotation:6.1f} deg {'-' if math.isnan(ate) else f'{ate:.1f}%':>6} "
                             f"{result.keyframe_fit_rms:4.2f} px")
            count += 1
            print(f"{out.name + '/' + run.name[:30]:<40}" + "".join(f"{c:>24}" for c in cells), flush=True)
    print(f"{'failures (> ' + str(FAILURE_DEG) + ' deg) of ' + str(count):<40}"
          + "".join(f"{failures[c]:>24}" for c in columns))
    print(f"{'time against seed 0 alone':<40}" + "".join(f"{seconds[c] / seconds['seed 0']:>23.2f}x" for c in columns))


if __name__ == "__main__":
    main()
