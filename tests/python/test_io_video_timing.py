"""Frame timing and undecodable videos. A variable-frame-rate clip (written by imageio-ffmpeg's FFmpeg with setpts and
-fps_mode vfr: 7 frames 1/24 s apart, then 7 frames 1/12 s apart) has each frame's time read from its timestamp,
checked against the presentation times FFmpeg's showinfo filter prints for the same file; the frames node warns
of the varying rate, and a full run writes the times into results.npz and flags the rate in results.json."""

import json
import logging
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from m3c.io.video import VideoError, frame_rate, frame_times, probe_video
from m3c.perception.mediapipe_pose import mediapipe_available
from m3c.pipeline import InputError, PipelineConfig, Runner

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
SIZE = (480, 270)
FIRST = 7  # frames at 24 fps, then as many at 12 fps


@pytest.fixture(scope="module")
def ffmpeg() -> str:
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="needs imageio-ffmpeg (the 'test' extra)")
    return imageio_ffmpeg.get_ffmpeg_exe()


def showinfo_times(ffmpeg: str, path: Path) -> np.ndarray:
    """Presentation times of every frame as FFmpeg's showinfo filter reports them (the independent reference)."""
    log = subprocess.run([ffmpeg, "-hide_banner", "-i", str(path), "-vf", "showinfo", "-f", "null", "-"],
                         capture_output=True, text=True, check=True).stderr
    return np.array([float(t) for t in re.findall(r"pts_time:\s*([-\d.]+)", log)])


@pytest.fixture(scope="module")
def clips(ffmpeg, tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("timing")
    constant, variable = folder / "constant.mp4", folder / "variable.mp4"
    cap = cv2.VideoCapture(str(EXAMPLE))
    writer = cv2.VideoWriter(str(constant), cv2.VideoWriter_fourcc(*"mp4v"), 24.0, SIZE)
    for _ in range(2 * FIRST):
        ok, frame = cap.read()
        assert ok
        writer.write(cv2.resize(frame, SIZE, interpolation=cv2.INTER_AREA))
    writer.release()
    cap.release()
    pts = f"if(lt(N,{FIRST}),N/24,{(FIRST - 1) / 24}+(N-{FIRST - 1})/12)/TB"
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-i", str(constant), "-vf", f"setpts='{pts}'",
                    "-fps_mode", "vfr", "-c:v", "libx264", "-pix_fmt", "yuv420p", str(variable)], check=True)
    return constant, variable


def test_frame_times_are_the_files_timestamps(ffmpeg, clips):
    constant, variable = clips
    for path in clips:
        reference = showinfo_times(ffmpeg, path)
        assert len(reference) == 2 * FIRST
        np.testing.assert_allclose(frame_times(path), reference - reference[0], atol=1e-3)
    times = frame_times(variable)
    steps = np.diff(times)
    np.testing.assert_allclose(steps[:FIRST - 1], 1 / 24, atol=2e-3)
    np.testing.assert_allclose(steps[FIRST - 1:], 1 / 12, atol=2e-3)
    rate = frame_rate(times)
    assert rate.variable and rate.fps == pytest.approx((len(times) - 1) / times[-1])
    assert rate.max_step / rate.min_step == pytest.approx(2.0, rel=0.05)
    steady = frame_rate(frame_times(constant))
    assert not steady.variable and steady.fps == pytest.approx(24.0, rel=1e-3)
    assert frame_rate(np.zeros(5)) is None and frame_rate(np.array([0.0])) is None  # no usable timestamps


def test_frames_node_reads_times_and_warns_of_a_variable_rate(clips, tmp_path, caplog):
    constant, variable = clips
    for path, varies in ((constant, False), (variable, True)):
        runner = Runner(PipelineConfig.default(), tmp_path / path.stem, {"video": path}, show_progress=False)
        with caplog.at_level(logging.WARNING, logger="m3c.nodes.frames"):
            caplog.clear()
            runner.run(["frames"])
        video = runner.cache.load("frames", runner.plan(["frames"])[0][1])["video"]
        np.testing.assert_array_equal(video["times"], frame_times(path))
        assert video["variable_rate"] is varies
        assert ("variable frame rate" in caplog.text) is varies
        expected_fps = frame_rate(video["times"]).fps if varies else probe_video(path).fps
        assert video["fps"] == pytest.approx(expected_fps)
    assert "41.7 to 83.3 ms" in caplog.text and "-fps_mode cfr" in caplog.text
    # A frame step keeps every step-th frame's own time.
    config = PipelineConfig.default().with_overrides({"frames.step": 3})
    runner = Runner(config, tmp_path / "step", {"video": variable}, show_progress=False)
    runner.run(["frames"])
    video = runner.cache.load("frames", runner.plan(["frames"])[0][1])["video"]
    np.testing.assert_array_equal(video["times"], frame_times(variable)[::3])


def test_slow_motion_gives_real_time(clips, tmp_path):
    """--slow-motion K: the frames' times are the file's divided by K and their rate K times the file's (real time),
    the playback rate stays the file's; a bad factor is refused naming the setting and the flag."""
    constant, variable = clips
    for path in (constant, variable):
        plain = Runner(PipelineConfig.default(), tmp_path / f"{path.stem}_1", {"video": path}, show_progress=False)
        plain.run(["frames"])
        base = plain.cache.load("frames", plain.plan(["frames"])[0][1])["video"]
        config = PipelineConfig.default().with_overrides({"frames.slow_motion": 4.0})
        slow = Runner(config, tmp_path / f"{path.stem}_4", {"video": path}, show_progress=False)
        slow.run(["frames"])
        video = slow.cache.load("frames", slow.plan(["frames"])[0][1])["video"]
        np.testing.assert_allclose(video["times"], frame_times(path) / 4.0)
        assert video["fps"] == pytest.approx(4.0 * base["fps"]) and video["playback_fps"] == pytest.approx(base["fps"])
        assert video["slow_motion"] == 4.0 and base["slow_motion"] == 1.0
        np.testing.assert_array_equal(video["frame_ids"], base["frame_ids"])
    for bad in (0.0, -2.0, float("nan"), float("inf")):
        config = PipelineConfig.default().with_overrides({"frames.slow_motion": bad})
        runner = Runner(config, tmp_path / "bad", {"video": constant}, show_progress=False)
        with pytest.raises(InputError, match="frames.slow_motion must be a number > 0.*--slow-motion"):
            runner.run(["frames"])


@pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (pip install 'm3c[perception]')")
@pytest.mark.slow
def test_results_carry_each_frames_time(clips, tmp_path):
    _, variable = clips
    out = tmp_path / "run"
    Runner(PipelineConfig.default(), out, {"video": variable}, show_progress=False).run(["results"])
    with np.load(out / "results.npz") as npz:
        np.testing.assert_array_equal(npz["times"], frame_times(variable))
        assert float(npz["fps"]) == pytest.approx(frame_rate(npz["times"]).fps)
    assert json.loads((out / "results.json").read_text())["video"]["variable_frame_rate"] is True


def test_undecodable_videos_are_refused_with_the_fix(ffmpeg, clips, tmp_path):
    constant, _ = clips
    # The stream opens, its pictures do not decode: an H.264 file (index first) with its media data zeroed.
    playable = tmp_path / "playable.mp4"
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-i", str(constant), "-c:v", "libx264", "-movflags",
                    "+faststart", str(playable)], check=True)
    data = bytearray(playable.read_bytes())
    start = data.index(b"mdat") + 4
    data[start:] = bytes(len(data) - start)
    damaged = tmp_path / "damaged.mp4"
    damaged.write_bytes(bytes(data))
    with pytest.raises(VideoError, match="damaged.mp4 holds no decodable frames .*codec 'h264'.*ffmpeg -i IN"):
        probe_video(damaged)
    data = constant.read_bytes()
    truncated = tmp_path / "truncated.mp4"
    truncated.write_bytes(data[:len(data) // 3])  # the index (moov) comes last: no stream to open
    with pytest.raises(VideoError, match="cannot open .*truncated.mp4.*convert it to H.264"):
        probe_video(truncated)
    text = tmp_path / "notes.mp4"
    text.write_text("not a video\n" * 100)
    runner = Runner(PipelineConfig.default(), tmp_path / "out", {"video": text}, show_progress=False)
    with pytest.raises(InputError, match="cannot open .*notes.mp4"):
        runner.run(["frames"])
