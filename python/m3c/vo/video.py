"""Video input for the patch VO (OpenCV's Python package, opencv-python-headless)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from m3c.io.video import open_capture
from m3c.vo.odometry import VisualOdometry, VOConfig, VOResult


def _cv2():
    try:
        import cv2
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("reading video needs OpenCV for Python: pip install opencv-python-headless") from e
    return cv2


def video_info(path: str | Path) -> dict:
    """{'width', 'height', 'fps', 'frame_count'} as the container reports them (frame_count may be
    approximate)."""
    cv2 = _cv2()
    cap = open_capture(path)
    if not cap.isOpened():
        raise FileNotFoundError(f"cannot open video {path}: missing file or a codec OpenCV cannot read")
    try:
        return {"width": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                "height": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                "fps": float(cap.get(cv2.CAP_PROP_FPS)),
                "frame_count": int(cap.get(cv2.CAP_PROP_FRAME_COUNT))}
    finally:
        cap.release()


def iter_video_frames(path: str | Path, gray: bool = True, max_frames: int | None = None,
                      stride: int = 1) -> Iterator[np.ndarray]:
    """Yields frames in order: uint8 (H, W) gray, or (H, W, 3) RGB when gray=False."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    cv2 = _cv2()
    cap = open_capture(path)
    if not cap.isOpened():
        raise FileNotFoundError(f"cannot open video {path}: missing file or a codec OpenCV cannot read")
    try:
        index = kept = 0
        while max_frames is None or kept < max_frames:
            ok, bgr = cap.read()
            if not ok:
                break
            if index % stride == 0:
                yield cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY if gray else cv2.COLOR_BGR2RGB)
                kept += 1
            index += 1
    finally:
        cap.release()


def read_video(path: str | Path, gray: bool = True, max_frames: int | None = None, stride: int = 1
               ) -> tuple[np.ndarray, float]:
    """All frames as one array ((T, H, W) gray or (T, H, W, 3) RGB, uint8) and the frame rate of the kept
    frames."""
    frames = list(iter_video_frames(path, gray=gray, max_frames=max_frames, stride=stride))
    if not frames:
        raise ValueError(f"video {path} has no decodable frames")
    return np.stack(frames), video_info(path)["fps"] / stride


def run_vo_video(path: str | Path, intrinsics=None, config: VOConfig | None = None, masks=None, depths=None,
                 max_frames: int | None = None, stride: int = 1) -> VOResult:
    """Patch VO on a video file, streaming the frames (memory stays flat for long videos).

    masks / depths: None, or sequences indexable by kept-frame number giving (H, W) arrays.
    The result's extra['fps'] is the frame rate of the kept frames.
    """
    vo = VisualOdometry(intrinsics=intrinsics, config=config)
    for t, frame in enumerate(iter_video_frames(path, gray=True, max_frames=max_frames, stride=stride)):
        vo.add_frame(frame, None if masks is None else masks[t], None if depths is None else depths[t])
    if vo.num_frames == 0:
        raise ValueError(f"video {path} has no decodable frames")
    result = vo.finish()
    result.extra["fps"] = video_info(path)["fps"] / stride
    return result
