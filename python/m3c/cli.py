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
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError, ImportError) as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
