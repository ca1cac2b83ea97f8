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


def _vo(args) -> int:
    from m3c.io import save_npz_atomic
    from m3c.vo import run_vo_video

    result = run_vo_video(args.video, intrinsics=args.intrinsics, max_frames=args.max_frames)
    out = Path(args.out)
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
