"""Video frames and the default camera. The frame rate is read from the video, never assumed."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.io.video import open_capture
from m3c.perception._cv import import_cv2


@dataclass(frozen=True)
class VideoInfo:
    path: str
    fps: float
    num_frames: int  # as the container reports it (the decoder may deliver fewer)
    width: int
    height: int


def _open(path: str | Path):
    cv2 = import_cv2()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video not found: {path}")
    capture = open_capture(path)
    if not capture.isOpened():
        raise ValueError(f"{path}: OpenCV cannot decode this video (is its codec supported by the installed "
                         "OpenCV build?)")
    return cv2, capture


def video_info(path: str | Path) -> VideoInfo:
    cv2, capture = _open(path)
    try:
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        info = VideoInfo(str(path), fps, int(capture.get(cv2.CAP_PROP_FRAME_COUNT)),
                         int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    finally:
        capture.release()
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"{path}: the container states no frame rate; re-encode it with one (ffmpeg -r)")
    return info


def read_frames(path: str | Path, max_frames: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """(index, RGB frame (H, W, 3) uint8) in order, up to max_frames."""
    cv2, capture = _open(path)
    try:
        index = 0
        while max_frames is None or index < max_frames:
            ok, bgr = capture.read()
            if not ok:
                break
            yield index, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            index += 1
    finally:
        capture.release()
