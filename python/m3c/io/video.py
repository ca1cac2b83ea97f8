"""Video files through OpenCV: probing, streaming frames (one at a time, never the whole video), writing.

Frame rate and size are read from the file, never assumed. Frame counts come from decoding: the container's
frame count (CAP_PROP_FRAME_COUNT) is an estimate that is wrong for some files.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.io.atomic import atomic_path


class VideoError(ValueError):
    """A video file is missing, unreadable or empty; the message names the file and the problem."""


def _cv2():
    try:
        import cv2
    except ImportError as err:  # pragma: no cover - opencv is a dependency
        raise VideoError("reading videos needs OpenCV: pip install opencv-python-headless") from err
    return cv2


def open_capture(path: str | Path):
    """cv2.VideoCapture of `path` that applies the file's rotation metadata (phone videos recorded upright store
    landscape pixels and a rotation flag): frames, width and height come out as the video is meant to be seen.
    OpenCV's FFmpeg backend does this by default; it is asked for here so no reader depends on that default."""
    cv2 = _cv2()
    cap = cv2.VideoCapture(str(path))
    if cap.isOpened():
        cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1)
    return cap


def default_intrinsics(width: int, height: int) -> np.ndarray:
    """(fx, fy, cx, cy) of a camera nobody calibrated: focal length sqrt(W^2 + H^2) pixels (a ~53 degree diagonal
    field of view, typical of phones, WHAM's choice and the synthetic scenes'), principal point at the centre. The
    rule lives in the C++ core (m3c::Intrinsics::Default, which the odometry applies when given no intrinsics);
    the frames node, perception and the tools take it from here. A size that is not positive is a ValueError
    (raised by the core's binding)."""
    from m3c import _core  # here, not at the top: reading videos needs no C++ core

    return np.array(_core.default_intrinsics(int(width), int(height)), dtype=np.float64)


@dataclass(frozen=True)
class VideoInfo:
    path: str
    fps: float
    width: int  # as displayed: after the rotation metadata is applied
    height: int
    frame_count_hint: int  # from the container; count_frames() decodes to get the exact number
    rotation: int = 0  # clockwise degrees (0/90/180/270) the stored pixels are turned for display (file metadata)


def probe_video(path: str | Path) -> VideoInfo:
    """Opens `path` and reads its frame rate, size and first frame. Raises VideoError with the reason."""
    cv2 = _cv2()
    path = Path(path)
    if not path.exists():
        raise VideoError(f"video not found: {path}")
    if not path.is_file():
        raise VideoError(f"not a video file: {path} is a folder")
    cap = open_capture(path)
    try:
        if not cap.isOpened():
            raise VideoError(f"cannot open {path} as a video (OpenCV/FFmpeg found no decodable stream); "
                             "convert it to H.264 .mp4, e.g. ffmpeg -i IN -c:v libx264 OUT.mp4")
        ok, frame = cap.read()
        if not ok or frame is None:
            code = int(cap.get(cv2.CAP_PROP_FOURCC))
            codec = "".join(chr((code >> 8 * k) & 0xFF) for k in range(4)).strip("\x00 ") or "unknown"
            raise VideoError(f"{path} holds no decodable frames (an empty or damaged video, or its codec {codec!r} "
                             "cannot be decoded by this OpenCV); convert it to H.264 .mp4, e.g. ffmpeg -i IN -c:v "
                             "libx264 OUT.mp4")
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        if not np.isfinite(fps) or fps <= 0:
            raise VideoError(f"{path} does not state a frame rate; re-encode it with one "
                             "(ffmpeg -i IN -r 30 OUT.mp4)")
        height, width = frame.shape[:2]
        return VideoInfo(str(path.resolve()), fps, int(width), int(height),
                         int(max(cap.get(cv2.CAP_PROP_FRAME_COUNT), 0)),
                         int(cap.get(cv2.CAP_PROP_ORIENTATION_META)) % 360)
    finally:
        cap.release()


def count_frames(path: str | Path, progress=None) -> int:
    """Number of decodable frames (grabs every frame; no pixel conversion)."""
    return len(frame_times(path, progress))


def frame_times(path: str | Path, progress=None) -> np.ndarray:
    """Presentation time (seconds from the stream's start, as FFmpeg reports it through CAP_PROP_POS_MSEC) of every
    decodable frame, in decoding order; its length is the number of frames. Grabs every frame, converts no pixels.
    A variable-frame-rate file (phones, screen recordings) has unequal steps here, which its nominal fps hides."""
    cv2 = _cv2()
    cap = open_capture(path)
    times = []
    try:
        while cap.grab():
            times.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
            if progress is not None:
                progress.update()
    finally:
        cap.release()
    return np.asarray(times, dtype=np.float64)


@dataclass(frozen=True)
class FrameRate:
    """The frame rate of a run of frames as their timestamps give it."""

    fps: float  # the mean rate, (n - 1) / (t_last - t_first)
    min_step: float  # seconds between consecutive frames: smallest, median, largest
    median_step: float
    max_step: float
    variable: bool  # some step differs from the median by more than VARIABLE_RATE_TOLERANCE of it


# Timestamps of a constant-rate file jitter by the container's time base (about a millisecond); a real change of
# rate (phones drop to 24 fps or less in the dark, hold frames while the scene is still) changes steps by far more.
VARIABLE_RATE_TOLERANCE = 0.1


def frame_rate(times: np.ndarray) -> FrameRate | None:
    """FrameRate of frames at `times` (seconds), None when the times cannot give one: fewer than 2 frames, or the
    times do not increase (a container without usable timestamps)."""
    times = np.asarray(times, dtype=np.float64)
    if len(times) < 2 or not np.isfinite(times).all():
        return None
    steps = np.diff(times)
    if not (steps > 0).all():
        return None
    median = float(np.median(steps))
    variable = bool(np.abs(steps - median).max() > VARIABLE_RATE_TOLERANCE * median)
    return FrameRate(float((len(times) - 1) / (times[-1] - times[0])), float(steps.min()), median,
                     float(steps.max()), variable)


_CONVERSIONS = {"bgr": None, "rgb": "COLOR_BGR2RGB", "gray": "COLOR_BGR2GRAY"}


def iter_frames(path: str | Path, start: int = 0, stop: int | None = None, step: int = 1, colour: str = "bgr") \
        -> Iterator[tuple[int, np.ndarray]]:
    """Yields (video frame id, frame) for ids start, start + step, ... < stop, upright (rotation metadata applied):
    uint8 H x W x 3 BGR (OpenCV's order, the default), H x W x 3 RGB (colour="rgb") or H x W (colour="gray").
    M3C's one video reader: every node, perception, the odometry and the tools read frames through it."""
    if start < 0 or step < 1 or (stop is not None and stop < start):
        raise ValueError(f"bad frame range start={start} stop={stop} step={step}")
    if colour not in _CONVERSIONS:
        raise ValueError(f"colour must be one of {sorted(_CONVERSIONS)}, got {colour!r}")
    cv2 = _cv2()
    conversion = None if _CONVERSIONS[colour] is None else getattr(cv2, _CONVERSIONS[colour])
    cap = open_capture(path)
    if not cap.isOpened():
        raise VideoError(f"cannot open {path} as a video (a missing file, or a codec OpenCV cannot read)")
    try:
        index = 0
        while stop is None or index < stop:
            if index < start or (index - start) % step:
                if not cap.grab():
                    return
            else:
                ok, frame = cap.read()
                if not ok:
                    return
                yield index, frame if conversion is None else cv2.cvtColor(frame, conversion)
            index += 1
    finally:
        cap.release()


def read_video(path: str | Path, colour: str = "gray", max_frames: int | None = None, step: int = 1) \
        -> tuple[np.ndarray, float]:
    """Every step-th frame, up to max_frames of them, as one array ((T, H, W) gray or (T, H, W, 3), uint8) and
    the frame rate of the kept frames. The whole clip in memory: for tests and tools on short clips; the
    pipeline streams frames with iter_frames."""
    info = probe_video(path)
    stop = None if max_frames is None else max_frames * step
    frames = [frame for _, frame in iter_frames(path, 0, stop, step, colour)]
    return np.stack(frames), info.fps / step


class VideoWriter:
    """Writes BGR frames to an .mp4 (MPEG-4 Part 2, readable everywhere OpenCV/FFmpeg are) atomically: the
    file appears complete at `path` on close(), or not at all."""

    def __init__(self, path: str | Path, fps: float, size: tuple[int, int]):
        cv2 = _cv2()
        self.path = Path(path)
        self.size = (int(size[0]), int(size[1]))
        self._atomic = atomic_path(self.path, suffix=".mp4")
        self._tmp = self._atomic.__enter__()
        self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), self.size)
        if not self._writer.isOpened():
            self._atomic.__exit__(VideoError, None, None)
            raise VideoError(f"OpenCV cannot write MPEG-4 video to {self.path}")
        self.frames = 0

    def write(self, frame: np.ndarray) -> None:
        if frame.shape[:2] != (self.size[1], self.size[0]) or frame.dtype != np.uint8:
            raise ValueError(f"frame must be uint8 of shape ({self.size[1]}, {self.size[0]}, 3), got "
                             f"{frame.dtype} {frame.shape}")
        self._writer.write(np.ascontiguousarray(frame))
        self.frames += 1

    def close(self) -> None:
        self._writer.release()
        self._atomic.__exit__(None, None, None)

    def abort(self) -> None:
        self._writer.release()
        self._atomic.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
