"""Plausibility of the world motion on real clips, where there is no ground truth (m3c.eval.plausibility): runs
the pipeline (until results; cached in --out) on each video and prints, per track, the mean and peak speed, the
path against the displacement, the slower foot's median speed, the time below the ground and the gait (steps a
minute, step length in metres and in leg lengths). Beside each clip,
the same figures of a reference motion measured in the same run: retargeted CMU motion capture walking
(131_01 frames 140-200), what a plausible walker scores.

    PYTHONPATH=python python3 bench/real_clips.py [VIDEO ...] [--out out/real_clips] [--static VIDEO ...]
    (default: the bundled clip, plus ../shared/data/video/*/*.mp4 when that folder exists)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from m3c.body import default_body_model
from m3c.eval.benchmark import load_clips
from m3c.eval.plausibility import results_plausibility, track_plausibility
from m3c.io.results import load_results
from m3c.nodes import register_builtin_nodes
from m3c.pipeline import PipelineConfig, Runner

ROOT = Path(__file__).resolve().parents[1]


def figures_line(name: str, f: dict) -> str:
    ratio = "-" if f["path_ratio"] is None else f"{f['path_ratio']:.1f}"
    return (f"{name:<44}{f['frames']:>6}{f['mean_speed_mps']:>7.2f}{f['peak_speed_mps']:>7.2f}"
            f"{f['path_length_m']:>7.2f}{f['displacement_m']:>7.2f}{ratio:>6}{f['slow_foot_speed_mps']:>7.2f}"
            f"{100 * f['below_ground_fraction']:>7.0f}{100 * f['penetration_m']:>7.1f}"
            + "".join("      -" if f[key] is None else f"{f[key]:>7.{digits}f}"
                      for key, digits in (("step_rate_spm", 0), ("step_length_m", 2), ("step_length_legs", 2))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("videos", nargs="*")
    parser.add_argument("--static", nargs="*", default=[], help="videos from a camera that stands still")
    parser.add_argument("--out", default="out/real_clips")
    args = parser.parse_args()
    videos = [Path(v) for v in args.videos]
    if not videos and not args.static:
        videos = [ROOT / "examples" / "pexels_walking_moving_camera.mp4"]
        videos += sorted((ROOT.parent / "shared" / "data" / "video").glob("*/*.mp4"))
    register_builtin_nodes()
    model = default_body_model()
    clip = next(c for c in load_clips() if "131" in c.info["name"])
    walk = slice(140, 200)
    reference = track_plausibility(model.joints(clip.pose()[walk], clip.betas, clip.transl[walk]), clip.fps)
    head = (f"{'clip / track':<44}{'frames':>6}{'mean':>7}{'peak':>7}{'path':>7}{'disp':>7}{'ratio':>6}"
            f"{'foot':>7}{'below%':>7}{'cm':>7}{'steps':>7}{'step':>7}{'legs':>7}")
    rows = [head, "-" * len(head), figures_line("reference: CMU 131_01 walking (mocap)", reference)]
    for video, static in [(v, False) for v in videos] + [(Path(v), True) for v in args.static]:
        config = PipelineConfig.default()
        if static or "static" in video.parent.name:
            config = config.with_overrides({"vo.static": True})
        out = Path(args.out) / video.stem
        start = time.perf_counter()
        try:
            Runner(config, out, {"video": video}, show_progress=False).run(["results"])
            _, arrays = load_results(out)
        except Exception as err:  # one clip failing does not hide the others' figures
            rows.append(f"{video.name}: FAILED: {type(err).__name__}: {err}")
            continue
        for track_id, figures in zip(arrays["track_ids"], results_plausibility(arrays)):
            if figures is not None:
                rows.append(figures_line(f"{video.name} #{track_id}", figures))
        rows.append(f"  ({time.perf_counter() - start:.0f} s)")
    print("speeds m/s (mean, peak: pelvis, horizontal, smoothed 0.5 s), path and displacement m, foot: median "
          "speed of the slower foot m/s, below: % of frames a foot joint is 2 cm under the ground, cm: deepest")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
