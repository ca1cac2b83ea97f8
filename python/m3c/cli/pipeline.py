"""`m3c run`, `m3c batch`, `m3c graph`, `m3c config`: the pipeline."""

from __future__ import annotations

import sys
from pathlib import Path

from m3c.cli.common import output_folder, setup_logging


def pipeline_config(args):
    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline import PipelineConfig, parse_override

    register_builtin_nodes()
    config = PipelineConfig.from_yaml(Path(args.config)) if args.config else PipelineConfig.default()
    overrides = {}
    if getattr(args, "intrinsics", None):
        overrides["camera.intrinsics"] = list(args.intrinsics)
    if getattr(args, "hfov", None) is not None:
        overrides["camera.hfov"] = float(args.hfov)
    if getattr(args, "force_intrinsics", False):
        overrides["camera.force_intrinsics"] = True
    if getattr(args, "no_hands", False):
        overrides["hands.enabled"] = False
    if getattr(args, "side_by_side", False):
        overrides["world_view.beside_video"] = True
    if getattr(args, "fps", None) is not None:
        overrides["frames.fps"] = float(args.fps)
    if getattr(args, "static_camera", False):
        overrides["vo.static"] = True
        for name, entry in config.nodes.items():
            if entry.type == "focal":
                overrides[f"{name}.motion"] = False  # a still camera's motion cannot tell its focal length
    if getattr(args, "slow_motion", None) is not None:
        overrides["frames.slow_motion"] = float(args.slow_motion)
    if getattr(args, "frames", None):
        start, stop, step = args.frames
        overrides.update({"frames.start": start, "frames.stop": stop, "frames.step": step})
    if getattr(args, "body_model", None):
        overrides["settings.body_model"] = str(Path(args.body_model).expanduser().resolve())
    if getattr(args, "checkpoints", None):
        overrides["settings.models_dir"] = str(Path(args.checkpoints).expanduser().resolve())
    if getattr(args, "visualize", False):
        overrides["settings.visualize"] = True
    for item in getattr(args, "set", None) or []:
        key, value = parse_override(item)
        overrides[key] = value
    return config.with_overrides(overrides) if overrides else config


def run(args) -> int:
    from m3c.io.manifest import mark_failed
    from m3c.pipeline import PipelineError, Runner

    setup_logging(args.verbose - args.quiet)
    output_folder(args.out)
    try:
        runner = Runner(pipeline_config(args), args.out, {"video": Path(args.video)},
                        show_progress=not args.no_progress)
    except (PipelineError, ValueError) as err:
        mark_failed(args.out, err)  # a folder of an earlier run: its results are not this command's
        raise
    report = runner.run(args.until)
    print(f"m3c: finished in {sum(r.seconds for r in report.records):.1f} s "
          f"({len(report.ran())} node(s) ran, {len(report.records) - len(report.ran())} reused from the cache)")
    if args.verbose - args.quiet >= 0:
        print(report.summary())
    for name in report.published:
        print(f"  {Path(args.out) / name}")
    return 0


def batch(args) -> int:
    import logging

    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline.batch import collect_videos, run_batch

    setup_logging(args.verbose - args.quiet)
    if args.verbose - args.quiet <= 0:  # one line per video, not one per node of every video
        for name in ("m3c.pipeline", "m3c.nodes"):
            logging.getLogger(name).setLevel(logging.WARNING)
    output_folder(args.out)
    videos = collect_videos(args.inputs)
    config = pipeline_config(args)
    report = run_batch(config, videos, args.out, use_ray=not args.sequential, address=args.address,
                       cpus_per_video=args.cpus_per_video, memory_per_video_gb=args.memory_per_video,
                       show_progress=not args.no_progress, setup=register_builtin_nodes)
    print(report.table())
    print(f"wrote {Path(args.out) / 'batch_summary.json'}")
    return 1 if report.failed else 0


def graph(args) -> int:
    from m3c.pipeline import Graph, render_dot

    config = pipeline_config(args)
    graph = Graph.from_config(config)
    status = None
    if args.status:
        import json

        report = json.loads((Path(args.status) / "cache" / "last_run.json").read_text())
        status = {r["name"]: r["status"] for r in report["records"]}
    dot = graph.to_dot(status)
    if args.out:
        print(f"wrote {render_dot(dot, Path(args.out))}")
    else:
        sys.stdout.write(dot)
    return 0


def config(args) -> int:
    from m3c.pipeline import default_config_path

    sys.stdout.write(default_config_path().read_text())
    return 0
