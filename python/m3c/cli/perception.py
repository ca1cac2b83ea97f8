"""`m3c vo`, `m3c perceive`: the camera trajectory and the people of a video, alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m3c.cli.common import output_folder


def vo(args) -> int:
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


def perceive(args) -> int:
    from m3c.perception import PerceptionConfig, run_perception

    config = PerceptionConfig.from_yaml(args.config) if args.config else PerceptionConfig()
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
