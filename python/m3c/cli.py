"""The `m3c` command line."""

from __future__ import annotations

import argparse
import sys

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
