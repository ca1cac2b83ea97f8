"""`m3c eval retarget|benchmark|video-benchmark|multiview|real-benchmark|3dpw`: evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m3c.cli.common import log_to_stderr, provenance


def _frame_slice(text: str | None):
    if not text:
        return None
    parts = text.split(":")
    if len(parts) not in (2, 3) or not all(p.strip().lstrip("-").isdigit() or p == "" for p in parts):
        raise ValueError(f"--frames must look like START:STOP or START:STOP:STEP, got {text!r}")
    return slice(*[int(p) if p else None for p in parts])


def eval_retarget(args) -> int:
    from m3c.body import default_body_model
    from m3c.eval.retarget import RetargetConfig, retarget

    model = default_body_model(args.body_model)
    config = RetargetConfig(fps=args.fps, up_axis=args.up, scale=args.scale)
    result = retarget(model, args.bvh, args.joint_map, config, frames=_frame_slice(args.frames))
    if args.source:
        result.source = args.source
    result.save(args.out)
    print(f"wrote {args.out}: {result.num_frames} frames at {result.fps:g} fps, {result.info['scale']:.5f} m per "
          f"BVH unit, fit error {result.fit_error_mm.mean():.1f} mm mean / {result.fit_error_mm.max():.1f} mm max")
    return 0


def _benchmark_clips(model, args, log) -> list[str]:
    """The benchmarks' motions: --clips, plus the shipped CMU clips unless --clips alone was given, plus every BVH
    under each --mocap folder (retargeted once, cached)."""
    from m3c.eval.benchmark import retarget_folder, shipped_clip_paths

    clips = [str(c) for c in args.clips or []]
    if not clips or args.mocap:
        clips = [str(c) for c in shipped_clip_paths()] + clips
    for folder in args.mocap or []:
        clips += [str(p) for p in retarget_folder(model, folder, args.cache, log)]
    return clips


def eval_benchmark(args) -> int:
    started = provenance(args)  # the code as the run starts (the tree may change during a long run)
    import json

    from m3c.body import default_body_model
    from m3c.eval.benchmark import BenchmarkConfig, run_benchmark
    from m3c.io.atomic import atomic_path
    from m3c.motion import OptimizerConfig

    model = default_body_model(args.body_model)
    log = None if args.quiet else log_to_stderr
    clips = _benchmark_clips(model, args, log)
    config = BenchmarkConfig(num_sequences=args.sequences, num_frames=args.frames, seed=args.seed,
                             max_people=args.max_people, camera_motions=tuple(args.cameras.split(",")),
                             clip_paths=tuple(str(c) for c in clips),
                             optimizer=OptimizerConfig.from_yaml(Path(args.optimizer_config))
                             if args.optimizer_config else None, vposer=args.vposer or "")
    report = run_benchmark(model, config, log)
    print(report.tables())
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps({**report.summary(), "provenance": started}, indent=1))
        print(f"wrote {args.json}")
    return 0


def eval_video_benchmark(args) -> int:
    started = provenance(args)  # the code as the run starts (the tree may change during a long run)
    from m3c.body import default_body_model
    from m3c.eval.video_benchmark import VideoBenchmarkConfig, run_video_benchmark, write_json

    model = default_body_model(args.body_model)
    log = None if args.quiet else log_to_stderr
    clips = _benchmark_clips(model, args, log)
    config = VideoBenchmarkConfig(num_sequences=args.sequences, num_frames=args.frames,
                                  cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()),
                                  max_people=args.people, seed=args.seed, width=args.size[0], height=args.size[1],
                                  supersample=args.supersample, clip_paths=tuple(clips),
                                  pipeline_config=args.config, overrides=tuple(args.set or ()),
                                  known_intrinsics=args.known_intrinsics, render_only=args.render_only,
                                  suite=args.suite, only=tuple(args.only))
    if args.config and not Path(args.config).is_file():
        raise FileNotFoundError(f"pipeline config not found: {args.config}")
    report = run_video_benchmark(model, config, args.out, log, show_progress=not args.quiet)
    print(report.text())
    if args.json:
        write_json(report, args.json, started)
        print(f"wrote {args.json}")
    return 0 if not any(s.error for s in report.sequences) else 1


def eval_multiview(args) -> int:
    started = provenance(args)  # the code as the run starts (the tree may change during a long run)
    import json

    from m3c.body import default_body_model
    from m3c.eval.multiview import run_multiview
    from m3c.io.atomic import atomic_path

    model = default_body_model(args.body_model)
    report = run_multiview(model, args.folder, args.out, args.config, tuple(args.set or ()), args.known_intrinsics,
                           args.cameras, None if args.quiet else log_to_stderr, show_progress=not args.quiet)
    print(report.text())
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps({**report.summary(), "provenance": started}, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0 if not any(v.error for v in report.views) else 1


def eval_real_benchmark(args) -> int:
    started = provenance(args)  # the code as the run starts (the tree may change during a long run)
    import json

    from m3c.body import default_body_model
    from m3c.eval.real_benchmark import DEFAULT_SEQUENCES, run_real_benchmark
    from m3c.io.atomic import atomic_path

    if args.config and not Path(args.config).is_file():
        raise FileNotFoundError(f"pipeline config not found: {args.config}")
    model = default_body_model(args.body_model)
    modes = ("true", "estimated") if args.intrinsics == "both" else (args.intrinsics,)
    report = run_real_benchmark(model, args.folder, args.out, tuple(args.sequences or DEFAULT_SEQUENCES),
                                args.frames, modes, args.euroc, args.config, tuple(args.set or ()),
                                None if args.quiet else log_to_stderr, show_progress=not args.quiet)
    print(report.text())
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps({**report.summary(), "provenance": started}, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0 if not any(s.error for s in report.sequences) else 1


def eval_3dpw(args) -> int:
    started = provenance(args)  # the code as the run starts (the tree may change during a long run)
    import json

    from m3c.body import BodyModel
    from m3c.eval.threedpw_eval import evaluate_3dpw, format_3dpw_tables
    from m3c.io.atomic import atomic_path

    results = {}
    for item in args.results:
        method, sep, folder = item.partition("=")
        if not sep or not method or not folder:
            raise ValueError(f"--results takes METHOD=FOLDER, got {item!r}")
        results[method] = folder
    models = {"male": BodyModel.from_file(args.smpl_male), "female": BodyModel.from_file(args.smpl_female),
              "neutral": BodyModel.from_file(args.smpl_neutral)}
    regressor = np.load(args.h36m_regressor) if args.h36m_regressor else None
    evaluation = evaluate_3dpw(args.root, args.split, results, models, regressor, args.sequences,
                               None if args.quiet else log_to_stderr)
    print(format_3dpw_tables(evaluation))
    if args.json:
        summary = {"provenance": started, "joints": evaluation["joints"], "methods": evaluation["methods"],
                   "sequences": {name: {"people": row["people"],
                                        **{m: {k: r.mean(k) for k in r.values} for m, r in row.items()
                                           if m != "people"}}
                                 for name, row in evaluation["sequences"].items()}}
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(summary, indent=1))
        print(f"wrote {args.json}")
    return 0
