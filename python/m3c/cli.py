"""The `m3c` command line."""

from __future__ import annotations

import argparse
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


def _eval_benchmark(args) -> int:
    import json

    from m3c.body import default_body_model
    from m3c.eval.benchmark import (BenchmarkConfig, run_benchmark, retarget_folder, shipped_clip_paths)
    from m3c.io.atomic import atomic_path
    from m3c.motion import OptimizerConfig

    model = default_body_model(args.body_model)
    log = None if args.quiet else _log
    clips = list(args.clips or [])
    if not clips or args.mocap:
        clips = list(shipped_clip_paths()) + clips
    for folder in args.mocap or []:
        clips += retarget_folder(model, folder, args.cache, log)
    config = BenchmarkConfig(num_sequences=args.sequences, num_frames=args.frames, seed=args.seed,
                             max_people=args.max_people, camera_motions=tuple(args.cameras.split(",")),
                             clip_paths=tuple(str(c) for c in clips),
                             optimizer=OptimizerConfig.from_yaml(Path(args.optimizer_config))
                             if args.optimizer_config else None)
    report = run_benchmark(model, config, log)
    print(report.tables())
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(report.summary(), indent=1))
        print(f"wrote {args.json}")
    return 0


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
    bm.add_argument("--mocap", action="append", metavar="DIR",
                    help="also use every BVH under DIR (retargeted once, cached); repeatable")
    bm.add_argument("--clips", nargs="+", metavar="NPZ", help="retargeted clips (m3c eval retarget) to use "
                    "instead of the shipped CMU clips")
    bm.add_argument("--cache", help="cache folder for retargeted BVH (default ~/.cache/m3c/mocap)")
    bm.add_argument("--optimizer-config", help="YAML optimizer config (default: the built-in recipe)")
    bm.add_argument("--body-model", help="body model file (default: the shipped open model)")
    bm.add_argument("--json", help="also write the figures to this JSON file")
    bm.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    bm.set_defaults(func=_eval_benchmark)

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


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
