"""The frames node: the video (frame rate, size, the processed frame range); stream_frames for nodes that read
its pixels."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.io.video import VideoError, frame_rate, frame_times, iter_frames, probe_video
from m3c.pipeline import InputError, Node, register_node


@register_node
class FramesNode(Node):
    """Reads the video's frame rate and size and counts its frames; selects frames start, start + step, ...
    < stop. Frames themselves are never stored: nodes that need pixels stream them with stream_frames().

    Output video: path, name, fps (of the processed frames: source fps / step; for a variable-rate video the mean
    rate of the processed frames' timestamps), source_fps, width, height (as displayed: a phone video's rotation
    metadata is applied to every frame read), rotation (its degrees), num_frames (T), frame_ids (T,) video frame id
    of each processed frame, times (T,) each processed frame's time in seconds (the file's timestamps; frame id /
    source fps when the file has none), variable_rate (the steps between the processed frames differ by more than
    VARIABLE_RATE_TOLERANCE), start, stop, step, slow_motion, playback_fps.

    slow_motion: how many times slower than it was filmed the video plays (a phone's 120 fps slow motion played at
    30 fps: 4). fps and times are then real time (the file's rate times slow_motion, its timestamps divided by
    it), so every speed, the optimizer's smoothing and motion prior and the exported animation run in real time;
    playback_fps stays the rate of the processed frames as the file plays them (the overlay and world videos).
    """

    type_name = "frames"
    level = "frame"
    sources = ("video",)
    outputs = ("video",)

    @dataclass
    class Config:
        start: int = 0
        stop: int | None = None  # exclusive; None = to the end
        step: int = 1
        slow_motion: float = 1.0  # the video plays this many times slower than real time (see the class docstring)
        fps: float | None = None  # the video's true frame rate when its file's is wrong (--fps); None: the file's

    def check(self, ctx) -> None:
        c = self.config
        if c.start < 0 or c.step < 1 or (c.stop is not None and c.stop <= c.start):
            raise InputError(f"bad frame range start={c.start} stop={c.stop} step={c.step}: need 0 <= start < stop "
                             "and step >= 1")
        if not (np.isfinite(c.slow_motion) and c.slow_motion > 0):
            raise InputError(f"frames.slow_motion must be a number > 0, got {c.slow_motion!r}: how many times slower "
                             "than it was filmed the video plays (1: real time; 4: 120 fps slow motion played at 30 "
                             "fps; --slow-motion FACTOR)")
        if c.fps is not None and not (np.isfinite(c.fps) and MIN_FPS <= c.fps <= MAX_FPS):
            raise InputError(f"frames.fps (--fps) must be a frame rate in [{MIN_FPS:g}, {MAX_FPS:g}], got {c.fps!r}")
        try:
            probe_video(ctx.source("video"))
        except VideoError as err:
            raise InputError(str(err)) from None

    def run(self, ctx, inputs):
        path = ctx.source("video")
        try:
            info = probe_video(path)
        except VideoError as err:
            raise InputError(str(err)) from None
        hint = info.frame_count_hint or None
        with ctx.progress("counting frames", hint) as bar:
            all_times = frame_times(path, bar)
        total = len(all_times)
        if total == 0:
            raise InputError(f"{path} holds no decodable frames")
        stop = total if self.config.stop is None else min(self.config.stop, total)
        frame_ids = np.arange(self.config.start, stop, self.config.step, dtype=np.int64)
        if len(frame_ids) == 0:
            raise InputError(f"frame range {self.config.start}:{self.config.stop} selects no frames; {path} has "
                             f"{total} frames (0 .. {total - 1})")
        if len(frame_ids) < 2:
            what = f"{path} has only 1 frame" if total == 1 else \
                f"frame range {self.config.start}:{self.config.stop}:{self.config.step} selects only 1 frame"
            raise InputError(f"{what}; motion capture needs at least 2 frames (people and camera are tracked "
                             "over time)")
        ctx.log.info("%s: %d x %d%s, %.3f fps, %d frames; processing %d", Path(path).name, info.width, info.height,
                     f" (turned {info.rotation} degrees as its metadata says)" if info.rotation else "", info.fps,
                     total, len(frame_ids))
        truncated = _truncation(info.frame_count_hint, total)
        if truncated:
            ctx.log.warning("%s: only %d of the %d frames its container lists decode (a cut or damaged file); the "
                            "run covers frames 0..%d, and results.json records it (video.frames_in_container)",
                            Path(path).name, total, info.frame_count_hint, total - 1)
        if self.config.fps is not None:
            fps = float(self.config.fps)
            ctx.log.info("%s: frame rate %.3f fps as given (--fps; the file states %.3f), frame times from frame ids",
                         Path(path).name, fps, info.fps)
            times, fps, variable = frame_ids / fps, fps / self.config.step, False
            source_fps = float(self.config.fps)
        else:
            _check_frame_rate(Path(path).name, info.fps, all_times)
            times, fps, variable = self._times(ctx, Path(path).name, all_times, frame_ids, info.fps)
            source_fps = info.fps
        slow = float(self.config.slow_motion)
        if slow != 1.0:
            ctx.log.info("slow motion x%g: the processed frames' %.3f fps of playback are %.3f fps of real time; "
                         "times, speeds and the exported animation are real time", slow, fps, fps * slow)
        return {"video": {"path": info.path, "name": Path(info.path).name, "fps": fps * slow,
                          "source_fps": source_fps, "width": info.width, "height": info.height,
                          "rotation": info.rotation, "num_frames": int(len(frame_ids)), "total_frames": int(total),
                          "frame_ids": frame_ids, "times": times / slow, "variable_rate": variable,
                          "start": self.config.start, "stop": int(stop), "step": self.config.step,
                          "slow_motion": slow, "playback_fps": fps,
                          "frames_in_container": int(info.frame_count_hint), "truncated": truncated}}

    def _times(self, ctx, name: str, all_times: np.ndarray, frame_ids: np.ndarray, source_fps: float) \
            -> tuple[np.ndarray, float, bool]:
        """(times of the processed frames, their frame rate, whether it varies). A constant-rate video keeps its
        stated rate (source fps / step); a variable-rate one gets its mean rate and a warning, since the optimizer's
        smoothness terms and motion prior step from frame to frame as if the steps were equal."""
        if frame_rate(all_times) is None:
            ctx.log.warning("%s has no increasing frame timestamps; frame times are taken as frame id / %.3f fps",
                            name, source_fps)
            return frame_ids / source_fps, source_fps / self.config.step, False
        times = all_times[frame_ids]
        rate = frame_rate(times)
        if not rate.variable:
            return times, source_fps / self.config.step, False
        ctx.log.warning(
            "%s has a variable frame rate: %.1f to %.1f ms between the processed frames (median %.1f ms; the file "
            "states %.3f fps). Each frame's time is read from its timestamp and written to the results (times), "
            "and the optimizer's smoothness and contact terms use these times, but its motion prior (HuMoR) treats "
            "consecutive frames as equally spaced (the mean rate, %.3f fps). For exact timing there too, convert it "
            "to a constant rate first (ffmpeg -i IN -fps_mode cfr -r %.0f OUT.mp4).",
            name, 1000 * rate.min_step, 1000 * rate.max_step, 1000 * rate.median_step, source_fps, rate.fps,
            round(rate.fps))
        return times, rate.fps, True


# A person's motion is tracked from frame to frame: a stated rate outside these is a broken header (a zero
# sample delta gave 1.2 fps), not a camera; --fps overrides it.
MIN_FPS, MAX_FPS = 5.0, 1000.0
# A constant-rate file whose timestamps step at a rate this far (relative) from the one it states is lying in one
# of the two; speeds would be off by the ratio.
FPS_MISMATCH = 0.1


def _truncation(container_frames: int, decoded: int) -> bool:
    """The container lists more frames than decode (beyond the slack of containers that count a frame or two
    more than they hold)."""
    return container_frames > 0 and container_frames - decoded > max(2, 0.01 * container_frames)


def _check_frame_rate(name: str, stated_fps: float, all_times: np.ndarray) -> None:
    """Refuses a stated frame rate that no camera has, or that the file's own constant-rate timestamps
    contradict, naming --fps as the way to give the true one."""
    if not MIN_FPS <= stated_fps <= MAX_FPS:
        raise InputError(f"{name} states {stated_fps:.4g} fps, which is not a plausible video frame rate "
                         f"([{MIN_FPS:g}, {MAX_FPS:g}]): its header is probably damaged, and every speed would be "
                         "off by the error. Give the true rate with --fps RATE (e.g. --fps 30), or re-encode the "
                         "file (ffmpeg -i IN -r 30 OUT.mp4)")
    rate = frame_rate(all_times)
    if rate is None or rate.variable:
        return
    if abs(rate.fps - stated_fps) > FPS_MISMATCH * stated_fps:
        raise InputError(f"{name} states {stated_fps:.3f} fps but its frame timestamps step at {rate.fps:.3f} fps; "
                         "one of the two is wrong and speeds would be off by their ratio "
                         f"({rate.fps / stated_fps:.2f}x). Give the true rate with --fps RATE")


def stream_frames(ctx, video: dict) -> Iterator[tuple[int, np.ndarray]]:
    """(processed frame index 0 .. T-1, BGR frame) for the frames the frames node selected, decoded one at a
    time from the run's video source."""
    ids = video["frame_ids"]
    expected = iter(range(len(ids)))
    for i, (frame_id, frame) in zip(expected, iter_frames(ctx.source("video"), int(video["start"]),
                                                          int(video["stop"]), int(video["step"]))):
        if frame_id != ids[i]:
            raise InputError(f"video frames changed while reading: expected frame {ids[i]}, got {frame_id}")
        yield i, frame
