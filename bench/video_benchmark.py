"""The ground-truth video benchmark (m3c eval video-benchmark) with the time of each stage, plus the renderer's
speed at 960 x 540: frames per second of the full scene (C++ rasteriser, m3c._core) and its ratio against the
numpy rasteriser (m3c.viz.raster) drawing only the same frames' people, measured in the same run.

    PYTHONPATH=python python3 bench/video_benchmark.py [--sequences 7] [--frames 150] [--out out/video_benchmark]
        [--cameras static,pan,...] [--seed 0] [--set NODE.KEY=VALUE] [--json FILE] [--render-speed-only]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from m3c.body import default_body_model
from m3c.eval.benchmark import load_clips
from m3c.eval.video_benchmark import VideoBenchmarkConfig, run_video_benchmark, write_json
from m3c.synth import CAMERA_KINDS, SequenceSpec, setup_sequence
from m3c.synth.render import camera_from_world_points
from m3c.viz.raster import Mesh, render


def render_speed(model, clips, frames: int = 30) -> None:
    spec = SequenceSpec(0, "follow", 3, num_frames=frames, width=960, height=540)
    setup = setup_sequence(model, clips, spec)
    verts = setup.bodies(0, frames)
    start = time.perf_counter()
    for i in range(frames):
        setup.frame(i, [v[i] for v in verts])
    cpp = (time.perf_counter() - start) / frames
    reference_frames = max(3, frames // 6)
    start = time.perf_counter()
    for i in range(reference_frames):
        meshes = [Mesh(camera_from_world_points(v[i], setup.world_from_cam[i]), model.faces) for v in verts]
        render(meshes, setup.intrinsics, 960, 540)
    numpy_people = (time.perf_counter() - start) / reference_frames
    print(
        f"renderer, 960 x 540, 3 people + textured world: {1 / cpp:.1f} frames/s ({1000 * cpp:.0f} ms/frame); "
        f"numpy rasteriser, the same people only: {1000 * numpy_people:.0f} ms/frame; ratio {numpy_people / cpp:.1f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=7)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--cameras", default=",".join(CAMERA_KINDS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="out/video_benchmark")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.KEY=VALUE")
    parser.add_argument("--config", help="pipeline config YAML")
    parser.add_argument("--json", help="write the summary here")
    parser.add_argument("--render-speed-only", action="store_true")
    args = parser.parse_args()

    model = default_body_model()
    clips = load_clips()
    render_speed(model, clips)
    if args.render_speed_only:
        return
    config = VideoBenchmarkConfig(
        num_sequences=args.sequences,
        num_frames=args.frames,
        cameras=tuple(args.cameras.split(",")),
        seed=args.seed,
        pipeline_config=args.config,
        overrides=tuple(args.set),
    )
    report = run_video_benchmark(model, config, args.out, log=lambda t: print(t, file=sys.stderr, flush=True))
    print(report.text())
    per_frame = {
        k: v
        / max(1, sum(s.num_people for s in report.sequences) and len(report.sequences) * config.num_frames)
        for k, v in report.stage_seconds().items()
    }
    print("per frame: " + ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in per_frame.items() if v > 0.0005))
    if args.json:
        write_json(report, args.json)
        print(f"wrote {args.json}")
    np.seterr(all="ignore")


if __name__ == "__main__":
    main()
