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


def render_speed(model, clips, frames: int = 24) -> None:
    """Full-scene frames per second, and people-only drawing against the numpy rasteriser on the same meshes,
    frame by frame in turn (so that load from other jobs hits both alike)."""
    spec = SequenceSpec(0, "follow", 3, num_frames=frames, width=960, height=540)
    setup = setup_sequence(model, clips, spec)
    verts = setup.bodies(0, frames)
    full = cpp = ref = 0.0
    for i in range(frames):
        bodies = [v[i] for v in verts]
        start = time.perf_counter()
        setup.frame(i, bodies)
        full += time.perf_counter() - start
        start = time.perf_counter()
        setup.frame(i, bodies, full=False)
        cpp += time.perf_counter() - start
        start = time.perf_counter()
        render([Mesh(camera_from_world_points(v, setup.world_from_cam[i]), model.faces) for v in bodies],
               setup.intrinsics, 960, 540)
        ref += time.perf_counter() - start
    print(f"renderer, 960 x 540, 3 people in the textured world: {frames / full:.1f} frames/s "
          f"({1000 * full / frames:.0f} ms/frame); the 3 people alone: C++ {1000 * cpp / frames:.0f} ms, numpy "
          f"rasteriser (m3c.viz.raster) {1000 * ref / frames:.0f} ms, ratio {ref / cpp:.1f}x")


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
    frames = len(report.sequences) * config.num_frames
    per_frame = {k: v / frames for k, v in report.stage_seconds().items()}
    print("per frame: " + ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in per_frame.items() if v > 0.0005))
    if args.json:
        write_json(report, args.json)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
