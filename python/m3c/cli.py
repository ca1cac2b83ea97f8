"""The `m3c` command line."""

from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path

import numpy as np


def _body_info(args) -> int:
    from m3c.body import BodyModel

    model = BodyModel.from_file(args.model, num_betas=None)
    data = model.data
    out = model.forward(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas))
    height = np.ptp(out.vertices[0, :, 1])
    print(f"{args.model}: {data.num_vertices} vertices, {data.num_joints} joints, {data.num_betas} shape "
          f"components, {len(data.faces)} faces, gender {data.gender}")
    print(f"rest pose: height (y extent) {height:.3f} m, weights per vertex "
          f"{(data.weights != 0).sum(1).mean():.2f}, J_regressor rows sum to "
          f"{data.J_regressor.sum(1).min():.4f}..{data.J_regressor.sum(1).max():.4f}")
    return 0


def _body_convert(args) -> int:
    from m3c.body import load_model_file
    from m3c.body.layouts import to_smpl_layout
    from m3c.io import save_npz_atomic

    data = load_model_file(args.model, num_betas=None)
    if args.smpl_layout:
        data = to_smpl_layout(data)
    kintree = np.stack([data.parents, np.arange(data.num_joints)])
    save_npz_atomic(args.out, v_template=data.v_template, shapedirs=data.shapedirs, posedirs=data.posedirs,
                    J_regressor=data.J_regressor, weights=data.weights, kintree_table=kintree, f=data.faces,
                    gender=np.array(data.gender))
    print(f"wrote {args.out} ({data.num_vertices} vertices, {data.num_joints} joints), readable without chumpy")
    return 0


def _vo(args) -> int:
    from m3c.io import save_npz_atomic
    from m3c.vo import run_vo_video

    out = output_folder(args.out)
    result = run_vo_video(args.video, intrinsics=args.intrinsics, max_frames=args.max_frames)
    save_npz_atomic(out / "camera_trajectory.npz", world_from_cam=result.world_from_cam.astype(np.float32),
                    intrinsics=result.intrinsics, fps=np.float64(result.extra["fps"]),
                    static_camera=np.bool_(result.static_camera),
                    **{f"quality_{k}": v for k, v in result.quality.items()})
    centres = result.camera_centres
    print(f"{args.video}: {len(centres)} frames, {result.message}")
    print(f"camera path length {np.linalg.norm(np.diff(centres, axis=0), axis=1).sum():.3f} (VO units; "
          f"monocular, so the scale is arbitrary), median tracking ratio {np.median(result.tracking_ratio):.2f}")
    try:
        from m3c.vo.plot import plot_trajectories
    except ImportError:
        plot_trajectories = None
    if plot_trajectories is not None:
        try:
            plot_trajectories(out / "camera_trajectory.png",
                              [{"title": Path(args.video).name, "curves": [("patch VO", result.world_from_cam)]}])
            print(f"wrote {out / 'camera_trajectory.npz'} and {out / 'camera_trajectory.png'}")
            return 0
        except ImportError:
            pass
    print(f"wrote {out / 'camera_trajectory.npz'} (install the 'viz' extra, matplotlib, for the plot)")
    return 0
def _frame_range(text: str) -> tuple[int, int | None, int]:
    """START:STOP[:STEP] (STOP exclusive, may be empty for the end)."""
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"expected START:STOP or START:STOP:STEP, got {text!r}")
    try:
        start = int(parts[0]) if parts[0] else 0
        stop = int(parts[1]) if parts[1] else None
        step = int(parts[2]) if len(parts) == 3 and parts[2] else 1
    except ValueError:
        raise argparse.ArgumentTypeError(f"frame range {text!r} must hold integers") from None
    return start, stop, step


def _pipeline_config(args):
    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline import PipelineConfig, parse_override

    register_builtin_nodes()
    config = PipelineConfig.from_yaml(Path(args.config)) if args.config else PipelineConfig.default()
    overrides = {}
    if getattr(args, "intrinsics", None):
        overrides["camera.intrinsics"] = list(args.intrinsics)
    if getattr(args, "static_camera", False):
        overrides["vo.static"] = True
        for name, entry in config.nodes.items():
            if entry.type == "perception":
                overrides[f"{name}.static_camera"] = True  # contacts from foot speeds in the camera frame
            if entry.type == "focal":
                overrides[f"{name}.enabled"] = False  # a still camera's motion cannot tell its focal length
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


def _setup_logging(verbosity: int) -> None:
    import logging

    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    logging.basicConfig(level=level, format="%(name)s: %(message)s", stream=sys.stderr)


def output_folder(path: str | Path) -> Path:
    """`path` as an output folder this process can create and write; ValueError naming the problem otherwise
    (an existing file, a folder under a file, no write permission, a read-only file system)."""
    import os
    import tempfile

    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"--out {path} is a file, not a folder; choose a folder (it is created if missing)")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"--out {path} lies under {existing}, which is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--out {path}: no permission to write in {existing}; choose a writable folder")
    try:
        with tempfile.TemporaryFile(dir=existing):  # a read-only file system passes os.access for root
            pass
    except OSError as err:
        raise ValueError(f"--out {path}: cannot write in {existing}: {err.strerror or err}") from None
    return path


def _run(args) -> int:
    from m3c.io.manifest import mark_failed
    from m3c.pipeline import PipelineError, Runner

    _setup_logging(args.verbose - args.quiet)
    output_folder(args.out)
    try:
        runner = Runner(_pipeline_config(args), args.out, {"video": Path(args.video)},
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


def _batch(args) -> int:
    import logging

    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline.batch import collect_videos, run_batch

    _setup_logging(args.verbose - args.quiet)
    if args.verbose - args.quiet <= 0:  # one line per video, not one per node of every video
        for name in ("m3c.pipeline", "m3c.nodes"):
            logging.getLogger(name).setLevel(logging.WARNING)
    output_folder(args.out)
    videos = collect_videos(args.inputs)
    config = _pipeline_config(args)
    report = run_batch(config, videos, args.out, use_ray=not args.sequential, address=args.address,
                       cpus_per_video=args.cpus_per_video, memory_per_video_gb=args.memory_per_video,
                       show_progress=not args.no_progress, setup=register_builtin_nodes)
    print(report.table())
    print(f"wrote {Path(args.out) / 'batch_summary.json'}")
    return 1 if report.failed else 0


def _info(args) -> int:
    from m3c.io.manifest import folder_state
    from m3c.io.results import PUBLISHED_FILES, describe

    print(describe(args.folder))
    state = folder_state(args.folder, PUBLISHED_FILES)
    if not state.complete:
        print(f"m3c: error: {args.folder}: {state.message}", file=sys.stderr)
        return EXIT_INPUT
    return 0


def _export(args) -> int:
    from m3c.export import export_results, parse_track_ids

    try:
        paths = export_results(args.folder, args.format, args.out, parse_track_ids(args.tracks), args.body_model,
                               bvh_unit=args.bvh_unit)
    except PermissionError as err:  # an unwritable --out: bad input, not a bug
        raise ValueError(str(err)) from None
    for path in paths:
        print(path)
    return 0


def _view(args) -> int:
    from m3c.viz.viewer import serve

    serve(args.folder, host=args.host, port=args.port, body_model=args.body_model, video=args.video)
    return 0


def _graph(args) -> int:
    from m3c.pipeline import Graph, render_dot

    config = _pipeline_config(args)
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


def _config(args) -> int:
    from m3c.pipeline import default_config_path

    sys.stdout.write(default_config_path().read_text())
    return 0


def _perceive(args) -> int:
    from m3c.perception import PerceptionConfig, run_perception

    config = PerceptionConfig.from_yaml(args.config) if args.config else PerceptionConfig()
    if args.static_camera:
        config.static_camera = True
    if args.intrinsics:
        config.intrinsics = tuple(args.intrinsics)
    for task in ("detector", "pose2d", "body"):
        name = getattr(args, task)
        if name:
            config.estimators[task].name, config.estimators[task].options = name, {}
    result = run_perception(args.video, config, max_frames=args.max_frames)
    result.save(args.out)
    out = Path(args.out)
    print(f"{args.video}: {result.num_frames} frames at {result.fps:.2f} fps, {len(result.tracks)} tracks -> "
          f"{out.with_suffix('.npz')}, {out.with_suffix('.json')}")
    for track in result.tracks:
        errors = track.bodies.reprojection_error_px[track.bodies.valid]
        median = f"{np.median(errors):.2f} px" if len(errors) else "n/a"
        print(f"  track {track.track_id}: frames {track.frame_ids[0]}..{track.frame_ids[-1]} "
              f"({len(track.frame_ids)} seen), body fits {int(track.bodies.valid.sum())}, median reprojection {median}")
    return 0


def _frame_slice(text: str | None):
    if not text:
        return None
    parts = text.split(":")
    if len(parts) not in (2, 3) or not all(p.strip().lstrip("-").isdigit() or p == "" for p in parts):
        raise ValueError(f"--frames must look like START:STOP or START:STOP:STEP, got {text!r}")
    return slice(*[int(p) if p else None for p in parts])


def _eval_retarget(args) -> int:
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


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _add_motion_options(parser) -> None:
    """The benchmarks' motion sources, read by _benchmark_clips."""
    parser.add_argument("--clips", nargs="+", metavar="NPZ", help="retargeted clips (m3c eval retarget) to use "
                        "instead of the shipped CMU clips")
    parser.add_argument("--mocap", action="append", metavar="DIR",
                        help="also use every BVH under DIR (retargeted once, cached); repeatable")
    parser.add_argument("--cache", help="cache folder for retargeted BVH (default ~/.cache/m3c/mocap)")


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


def _eval_benchmark(args) -> int:
    import json

    from m3c.body import default_body_model
    from m3c.eval.benchmark import BenchmarkConfig, run_benchmark
    from m3c.io.atomic import atomic_path
    from m3c.motion import OptimizerConfig

    model = default_body_model(args.body_model)
    log = None if args.quiet else _log
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
            tmp.write_text(json.dumps(report.summary(), indent=1))
        print(f"wrote {args.json}")
    return 0


def _eval_video_benchmark(args) -> int:
    from m3c.body import default_body_model
    from m3c.eval.video_benchmark import VideoBenchmarkConfig, run_video_benchmark, write_json

    model = default_body_model(args.body_model)
    log = None if args.quiet else _log
    clips = _benchmark_clips(model, args, log)
    config = VideoBenchmarkConfig(num_sequences=args.sequences, num_frames=args.frames,
                                  cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()),
                                  max_people=args.people, seed=args.seed, width=args.size[0], height=args.size[1],
                                  supersample=args.supersample, clip_paths=tuple(clips),
                                  pipeline_config=args.config, overrides=tuple(args.set or ()),
                                  known_intrinsics=args.known_intrinsics, render_only=args.render_only)
    if args.config and not Path(args.config).is_file():
        raise FileNotFoundError(f"pipeline config not found: {args.config}")
    report = run_video_benchmark(model, config, args.out, log, show_progress=not args.quiet)
    print(report.text())
    if args.json:
        write_json(report, args.json)
        print(f"wrote {args.json}")
    return 0 if not any(s.error for s in report.sequences) else 1


def _eval_multiview(args) -> int:
    import json

    from m3c.body import default_body_model
    from m3c.eval.multiview import run_multiview
    from m3c.io.atomic import atomic_path

    model = default_body_model(args.body_model)
    report = run_multiview(model, args.folder, args.out, args.config, tuple(args.set or ()), args.known_intrinsics,
                           args.cameras, None if args.quiet else _log, show_progress=not args.quiet)
    print(report.text())
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(report.summary(), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0 if not any(v.error for v in report.views) else 1


def _eval_3dpw(args) -> int:
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
                               None if args.quiet else _log)
    print(format_3dpw_tables(evaluation))
    if args.json:
        summary = {"joints": evaluation["joints"], "methods": evaluation["methods"],
                   "sequences": {name: {"people": row["people"],
                                        **{m: {k: r.mean(k) for k in r.values} for m, r in row.items()
                                           if m != "people"}}
                                 for name, row in evaluation["sequences"].items()}}
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(summary, indent=1))
        print(f"wrote {args.json}")
    return 0


# The video benchmark's camera motions (m3c.synth.cameras.CAMERA_KINDS; listed here so --help imports nothing).
CAMERA_KINDS_TEXT = ("static", "pan", "follow", "tracking", "orbit", "handheld", "high")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="m3c", description="M3C: world-grounded human motion capture.")
    sub = parser.add_subparsers(dest="command", required=True)
    body = sub.add_parser("body", help="inspect or convert SMPL-layout body model files").add_subparsers(
        dest="body_command", required=True)
    info = body.add_parser("info", help="summarise a .pkl/.npz body model file")
    info.add_argument("model")
    info.set_defaults(func=_body_info)
    convert = body.add_parser("convert", help="rewrite a .pkl/.npz model (e.g. a chumpy pickle) as a plain .npz")
    convert.add_argument("model")
    convert.add_argument("out")
    convert.add_argument("--smpl-layout", action="store_true", help="reduce SMPL-H/SMPL-X to SMPL's 24 joints")
    convert.set_defaults(func=_body_convert)
    vo = sub.add_parser("vo", help="camera trajectory of a video (patch visual odometry, no people masked yet)")
    vo.add_argument("video")
    vo.add_argument("--out", required=True, help="output folder")
    vo.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                    help="pixels; default f = sqrt(W^2 + H^2), principal point at the centre")
    vo.add_argument("--max-frames", type=int)
    vo.set_defaults(func=_vo)

    run = sub.add_parser("run", help="capture every person's 3D motion in a video",
                         description="Runs the pipeline on VIDEO; results, videos and the cache go to --out. "
                                     "A second run reuses every node whose inputs and settings are unchanged.")
    run.add_argument("video", help="input video file (any format OpenCV/FFmpeg reads)")
    run.add_argument("--out", required=True, help="output folder (results.npz/json, overlay.mp4, world.mp4, cache/)")
    _add_config_options(run)
    run.add_argument("--intrinsics", nargs=4, type=float, metavar=("FX", "FY", "CX", "CY"),
                     help="camera intrinsics in pixels (default: focal sqrt(W^2 + H^2), image centre)")
    run.add_argument("--static-camera", action="store_true", help="the camera does not move (no visual odometry)")
    run.add_argument("--frames", type=_frame_range, metavar="START:STOP[:STEP]",
                     help="process frames START..STOP-1 (every STEP-th)")
    run.add_argument("--body-model", metavar="FILE", help="SMPL-layout body model .pkl/.npz (default: the open model)")
    run.add_argument("--checkpoints", metavar="DIR", help="folder of learned-model checkpoints (default: $M3C_MODELS)")
    run.add_argument("--until", nargs="+", metavar="NODE", help="run only these nodes and what they need")
    run.add_argument("--visualize", action="store_true", help="also write each node's pictures under OUT/viz/")
    run.add_argument("--no-progress", action="store_true", help="no progress lines")
    run.add_argument("-v", "--verbose", action="count", default=0)
    run.add_argument("-q", "--quiet", action="count", default=0)
    run.set_defaults(func=_run)

    batch = sub.add_parser("batch", help="run the pipeline on many videos (on Ray when installed)",
                           description="Runs every video of INPUTS as `m3c run` would, into OUT/<video name>/ (each "
                                       "with its own cache: a re-run skips finished videos and resumes unfinished "
                                       "ones). Failed videos are reported and the others go on; OUT/batch_summary.json "
                                       "holds every video's outcome. Exit status 1 when any video failed.")
    batch.add_argument("inputs", nargs="+", metavar="INPUT",
                       help="video files, folders of videos, or .txt files listing one video or folder per line")
    batch.add_argument("--out", required=True, help="output folder (one result folder per video)")
    batch.add_argument("--address", help="Ray cluster address, or auto for the one running on this machine "
                       "(default: start a local Ray instance for this batch)")
    batch.add_argument("--sequential", action="store_true", help="run the videos one after another here, not on Ray")
    batch.add_argument("--cpus-per-video", type=float, help="CPUs Ray reserves per video (default: the most any "
                       "node of the pipeline needs, its `needs` in the config)")
    batch.add_argument("--memory-per-video", type=float, metavar="GB",
                       help="memory Ray reserves per video, GB (default: the most any node of the pipeline needs)")
    _add_config_options(batch)
    batch.add_argument("--intrinsics", nargs=4, type=float, metavar=("FX", "FY", "CX", "CY"),
                       help="camera intrinsics in pixels, the same for every video")
    batch.add_argument("--static-camera", action="store_true", help="the cameras do not move (no visual odometry)")
    batch.add_argument("--frames", type=_frame_range, metavar="START:STOP[:STEP]",
                       help="process frames START..STOP-1 (every STEP-th) of each video")
    batch.add_argument("--body-model", metavar="FILE", help="SMPL-layout body model .pkl/.npz (default: the open "
                                                            "model)")
    batch.add_argument("--checkpoints", metavar="DIR", help="folder of learned-model checkpoints (default: "
                                                            "$M3C_MODELS)")
    batch.add_argument("--no-progress", action="store_true", help="no progress lines")
    batch.add_argument("-v", "--verbose", action="count", default=0)
    batch.add_argument("-q", "--quiet", action="count", default=0)
    batch.set_defaults(func=_batch)

    info = sub.add_parser("info", help="summarise the results in an output folder")
    info.add_argument("folder")
    info.set_defaults(func=_info)

    export = sub.add_parser("export", help="write the results as BVH, GLB or FBX, or in WHAM/SLAHMR/GVHMR layouts",
                            description="Exports OUT_DIR's results (see README, 'Use the results' for axes and "
                                        "units of each format).")
    export.add_argument("folder", metavar="OUT_DIR", help="a result folder of `m3c run`")
    export.add_argument("--format", required=True, choices=("bvh", "glb", "fbx", "wham", "slahmr", "gvhmr"))
    export.add_argument("--tracks", metavar="IDS", help="comma-separated track ids (default: every track)")
    export.add_argument("--out", metavar="PATH", help="output file or folder (default: OUT_DIR/export/...)")
    export.add_argument("--body-model", metavar="FILE", help="the body model file the run used, when it was not "
                                                             "M3C's open model")
    export.add_argument("--bvh-unit", choices=("cm", "m"), default="cm", help="BVH length unit (default cm)")
    export.set_defaults(func=_export)

    view = sub.add_parser("view", help="interactive 3D viewer of a result folder in the browser (viser)")
    view.add_argument("folder", metavar="OUT_DIR", help="a result folder of `m3c run`")
    view.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    view.add_argument("--port", type=int, default=8080, help="port (default 8080)")
    view.add_argument("--body-model", metavar="FILE", help="the body model file the run used, when it was not "
                                                           "M3C's open model")
    view.add_argument("--video", metavar="FILE", help="show the source video's frames (default: OUT_DIR/overlay.mp4)")
    view.set_defaults(func=_view)

    graph = sub.add_parser("graph", help="draw the pipeline graph (Graphviz dot text, or .svg/.png via `dot`)")
    _add_config_options(graph)
    graph.add_argument("--out", metavar="FILE", help="write FILE (.dot, .svg, .png, .pdf) instead of printing dot")
    graph.add_argument("--status", metavar="DIR", help="colour nodes by the last run in output folder DIR")
    graph.set_defaults(func=_graph)

    config = sub.add_parser("config", help="print the default pipeline config (YAML) to start your own from")
    config.set_defaults(func=_config)
    perceive = sub.add_parser("perceive", help="people, keypoints, masks, camera-local bodies, tracks and contacts "
                                               "from a video (offline, CPU)")
    perceive.add_argument("video")
    perceive.add_argument("out", help="output path; OUT.npz and OUT.json are written")
    perceive.add_argument("--config", help="perception settings (YAML: estimators by task, tracker, ...)")
    perceive.add_argument("--max-frames", type=int, default=None)
    perceive.add_argument("--static-camera", action="store_true", help="the camera does not move")
    perceive.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                          help="pixels (default: focal length = image diagonal, principal point at the centre)")
    perceive.add_argument("--detector", help="detector estimator name (see m3c.perception.available)")
    perceive.add_argument("--pose2d", help="2D pose estimator name")
    perceive.add_argument("--body", help="camera-local body estimator name")
    perceive.set_defaults(func=_perceive)

    ev = sub.add_parser("eval", help="evaluation: metrics tables, benchmark, mocap retargeting").add_subparsers(
        dest="eval_command", required=True)
    rt = ev.add_parser("retarget", help="fit the body model to a BVH clip (IK) and save its parameters (.npz)")
    rt.add_argument("bvh")
    rt.add_argument("out")
    rt.add_argument("--frames", help="BVH frames START:STOP[:STEP] (e.g. 1: drops CMU's added T-pose)")
    rt.add_argument("--fps", type=float, default=30.0, help="output frame rate (default 30)")
    rt.add_argument("--up", choices=("y", "z"), default="y", help="the BVH's up axis (default y)")
    rt.add_argument("--scale", type=float, help="metres per BVH unit (default: from the skeleton)")
    rt.add_argument("--joint-map", help="cmu_3dsmax, cmu_motionbuilder or bandai_namco (default: detected)")
    rt.add_argument("--body-model", help="body model file (default: the shipped open model)")
    rt.add_argument("--source", help="a description of the clip stored in the file")
    rt.set_defaults(func=_eval_retarget)

    bm = ev.add_parser("benchmark", help="the ground-truth benchmark on retargeted mocap: Local and Global Opt "
                       "metrics tables (mm)")
    bm.add_argument("--sequences", type=int, default=2, help="number of sequences (default 2)")
    bm.add_argument("--frames", type=int, default=120, help="frames per sequence at 30 fps (default 120)")
    bm.add_argument("--seed", type=int, default=0)
    bm.add_argument("--max-people", type=int, default=3, choices=(1, 2, 3))
    bm.add_argument("--cameras", default="walking,panning,orbiting,static",
                    help="camera motions, used in turn (default walking,panning,orbiting,static)")
    _add_motion_options(bm)
    bm.add_argument("--optimizer-config", help="YAML optimizer config (default: the built-in recipe)")
    bm.add_argument("--vposer", help="exported vposer.safetensors (python -m m3c.models.export) for the optimizer's "
                    "pose prior (default: none; the pose_prior terms are then reported unavailable)")
    bm.add_argument("--body-model", help="body model file (default: the shipped open model)")
    bm.add_argument("--json", help="also write the figures to this JSON file")
    bm.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    bm.set_defaults(func=_eval_benchmark)

    vb = ev.add_parser("video-benchmark", help="render mocap people into textured scenes filmed by known moving "
                       "cameras, run the real pipeline on the videos and score it against the ground truth")
    vb.add_argument("--sequences", type=int, default=7, help="number of sequences (default 7: one per camera motion)")
    vb.add_argument("--frames", type=int, default=150, help="frames per sequence at 30 fps (default 150)")
    vb.add_argument("--cameras", default=",".join(CAMERA_KINDS_TEXT),
                    help=f"camera motions, used in turn (default {','.join(CAMERA_KINDS_TEXT)})")
    vb.add_argument("--people", type=int, default=3, choices=(1, 2, 3), help="most people in a sequence (default 3)")
    _add_motion_options(vb)
    vb.add_argument("--seed", type=int, default=0)
    vb.add_argument("--size", type=int, nargs=2, default=(960, 540), metavar=("W", "H"),
                    help="image size in pixels (default 960 540)")
    vb.add_argument("--supersample", type=int, default=1, help="samples per pixel along each axis (default 1; "
                    "textures are mip-mapped either way)")
    vb.add_argument("--out", default="out/video_benchmark", help="folder for the videos, ground truth and runs "
                    "(default out/video_benchmark; both are cached there)")
    vb.add_argument("--render-only", action="store_true", help="write the videos and ground truth only")
    vb.add_argument("--known-intrinsics", action="store_true", help="give the pipeline the true intrinsics "
                    "(default: it runs uncalibrated, as on a user's video)")
    _add_config_options(vb)
    vb.add_argument("--body-model", help="body model file (default: the shipped open model)")
    vb.add_argument("--json", help="also write the figures to this JSON file")
    vb.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    vb.set_defaults(func=_eval_video_benchmark)

    mv = ev.add_parser("multiview", help="run M3C on each video of a calibrated multi-camera recording alone and "
                       "compare with the calibration and the triangulated 3D keypoints")
    mv.add_argument("folder", nargs="?", default="examples/pose2sim_single_person",
                    help="Pose2Sim-layout folder: Calib_qualisys.toml, a .trc, videos/ (default: the repository's "
                    "examples/pose2sim_single_person)")
    mv.add_argument("--out", default="out/multiview", help="folder for the runs (cached; default out/multiview)")
    mv.add_argument("--cameras", nargs="+", metavar="NAME", help="only these cameras (e.g. cam_01)")
    mv.add_argument("--known-intrinsics", action="store_true", help="give the pipeline the calibrated intrinsics")
    _add_config_options(mv)
    mv.add_argument("--body-model", help="body model file (default: the shipped open model)")
    mv.add_argument("--json", help="also write the figures to this JSON file")
    mv.add_argument("--quiet", action="store_true")
    mv.set_defaults(func=_eval_multiview)

    pw = ev.add_parser("3dpw", help="evaluate prediction files on 3DPW (users bring the dataset and SMPL)")
    pw.add_argument("root", help="the 3DPW folder that holds sequenceFiles/")
    pw.add_argument("--split", default="test", choices=("train", "validation", "test"))
    pw.add_argument("--results", nargs="+", required=True, metavar="METHOD=FOLDER",
                    help="per method, a folder of <sequence>.npz prediction files (layout: m3c.eval.threedpw_eval)")
    pw.add_argument("--smpl-neutral", required=True, help="SMPL neutral model file (.pkl/.npz), for predictions")
    pw.add_argument("--smpl-male", required=True, help="SMPL male model file, for the ground truth")
    pw.add_argument("--smpl-female", required=True, help="SMPL female model file, for the ground truth")
    pw.add_argument("--h36m-regressor", help="J_regressor_h36m.npy (17 x 6890): the 14 evaluation joints; "
                    "without it SMPL's 24 joints are used")
    pw.add_argument("--sequences", nargs="+", help="only these sequence names")
    pw.add_argument("--json", help="also write the figures to this JSON file")
    pw.add_argument("--quiet", action="store_true")
    pw.set_defaults(func=_eval_3dpw)
    return parser


def _add_config_options(parser) -> None:
    parser.add_argument("--config", metavar="FILE", help="pipeline config YAML (default: the built-in one; see "
                                                         "`m3c config`)")
    parser.add_argument("--set", action="append", metavar="NODE.SETTING=VALUE",
                        help="change one setting, e.g. --set optimize.enabled=false (repeatable)")


# Exit codes: 0 success, 1 internal error (a bug: please report it with the traceback), 2 bad input or
# configuration, 3 a component or model file the run needs is not available, 130 interrupted.
EXIT_INPUT, EXIT_UNAVAILABLE = 2, 3
_USER_OS_ERRORS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.ENOTDIR,
                   errno.EISDIR}


def main(argv: list[str] | None = None) -> int:
    from m3c.pipeline import ComponentUnavailable, PipelineError, PipelineUnavailable

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except PipelineUnavailable as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        if getattr(args, "out", None) and Path(args.out).is_dir():
            print(f"m3c: nothing was computed that depends on them; the cache in {args.out} is kept", file=sys.stderr)
        return EXIT_UNAVAILABLE
    except (ComponentUnavailable, ImportError) as err:  # ImportError: an optional backend is not installed
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    except (PipelineError, FileNotFoundError, ValueError) as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as err:
        if err.errno not in _USER_OS_ERRORS:
            raise
        # The file system refused a write or read the user can fix (permissions, a full or read-only disk).
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("m3c: interrupted; finished nodes are cached, run the same command again to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
