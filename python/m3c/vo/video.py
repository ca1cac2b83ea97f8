"""The patch VO on a video file, its frames streamed through M3C's one reader (m3c.io.video)."""

from __future__ import annotations

from pathlib import Path

from m3c.io.video import iter_frames, probe_video
from m3c.vo.odometry import VisualOdometry, VOConfig, VOResult


def run_vo_video(path: str | Path, intrinsics=None, config: VOConfig | None = None, masks=None, depths=None,
                 max_frames: int | None = None, stride: int = 1) -> VOResult:
    """Patch VO on a video file, streaming the frames (memory stays flat for long videos).

    masks / depths: None, or sequences indexable by kept-frame number giving (H, W) arrays.
    The result's extra['fps'] is the frame rate of the kept frames.
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    info = probe_video(path)
    vo = VisualOdometry(intrinsics=intrinsics, config=config)
    stop = None if max_frames is None else max_frames * stride
    for t, (_, frame) in enumerate(iter_frames(path, 0, stop, stride, colour="gray")):
        vo.add_frame(frame, None if masks is None else masks[t], None if depths is None else depths[t])
    if vo.num_frames == 0:
        raise ValueError(f"video {path} has no decodable frames")
    result = vo.finish()
    result.extra["fps"] = info.fps / stride
    return result
