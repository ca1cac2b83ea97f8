"""Input that lies gets an error or a visible warning, never a silent "complete" (issue 59): a cut video whose
container lists more frames than decode, a frame rate no camera has or that the file's timestamps contradict,
intrinsics of no physical camera, a device or checkpoint folder that is not there, and people faster than any
person."""

import logging
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from m3c.cli import main
from m3c.eval.plausibility import MAX_HUMAN_SPEED_MPS, track_plausibility
from m3c.io.video import probe_video

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"


@pytest.fixture(scope="module")
def ffmpeg() -> str:
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="needs imageio-ffmpeg (the 'test' extra)")
    return imageio_ffmpeg.get_ffmpeg_exe()


def frames_only_config(tmp_path):
    path = tmp_path / "frames.yaml"
    path.write_text("nodes:\n  frames: {}\n  camera: {inputs: {video: frames.video}}\n")
    return path


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def frames_output(out: Path) -> dict:
    from m3c.pipeline.cache import Cache

    cache = Cache(out / "cache")
    (entry,) = [p for p in (out / "cache" / "frames").iterdir() if (p / "outputs.json").is_file()]
    return cache.load("frames", entry.name)["video"]


@pytest.fixture(scope="module")
def clip(ffmpeg, tmp_path_factory) -> Path:
    """40 frames of the bundled clip at 25 fps, H.264 with its index first (a phone's or a web file's layout)."""
    folder = tmp_path_factory.mktemp("lying")
    raw = folder / "raw.mp4"
    cap = cv2.VideoCapture(str(EXAMPLE))
    writer = cv2.VideoWriter(str(raw), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (320, 180))
    for _ in range(40):
        ok, frame = cap.read()
        assert ok
        writer.write(cv2.resize(frame, (320, 180), interpolation=cv2.INTER_AREA))
    writer.release()
    cap.release()
    path = folder / "clip.mp4"
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-i", str(raw), "-c:v", "libx264", "-g", "5", "-pix_fmt",
                    "yuv420p", "-movflags", "+faststart", str(path)], check=True)
    return path


def test_cut_video_is_reported_and_recorded(clip, tmp_path, capsys, caplog):
    """The first 30% of the file: the container still lists 40 frames, about a third decode."""
    cut = tmp_path / "cut.mp4"
    data = clip.read_bytes()
    cut.write_bytes(data[:int(0.3 * len(data))])
    assert probe_video(cut).frame_count_hint == 40
    with caplog.at_level(logging.WARNING, logger="m3c.nodes.frames"):
        code, _, err = run_cli(capsys, "run", cut, "--out", tmp_path / "out", "--config",
                               frames_only_config(tmp_path))
    assert code == 0, err
    video = frames_output(tmp_path / "out")
    assert video["truncated"] and video["frames_in_container"] == 40 and 2 <= video["total_frames"] < 30
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(f"only {video['total_frames']} of the 40 frames" in w for w in warnings), warnings
    # the whole file: nothing reported
    code, _, _ = run_cli(capsys, "run", clip, "--out", tmp_path / "whole", "--config", frames_only_config(tmp_path))
    whole = frames_output(tmp_path / "whole")
    assert code == 0 and not whole["truncated"] and whole["total_frames"] == 40


def _retimed(ffmpeg, clip, tmp_path, rate: str, name: str) -> Path:
    """The clip's frames re-timed to `rate` frames a second (timestamps and stated rate agree)."""
    out = tmp_path / name
    subprocess.run([ffmpeg, "-y", "-loglevel", "error", "-i", str(clip), "-vf", f"setpts=N/({rate}*TB)", "-r", rate,
                    "-c:v", "libx264", "-pix_fmt", "yuv420p", str(out)], check=True)
    return out


def test_implausible_frame_rate_is_refused_unless_given(ffmpeg, clip, tmp_path, capsys):
    slow = _retimed(ffmpeg, clip, tmp_path, "1.2", "slow.mp4")
    assert abs(probe_video(slow).fps - 1.2) < 0.05
    code, _, err = run_cli(capsys, "run", slow, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path))
    assert code == 2 and "1.2 fps, which is not a plausible video frame rate" in err and "--fps" in err, err
    code, _, err = run_cli(capsys, "run", slow, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--fps", "25")
    video = frames_output(tmp_path / "out")
    assert code == 0 and video["fps"] == 25.0 and abs(video["times"][10] - 0.4) < 1e-9


def test_frame_rate_contradicted_by_timestamps_is_refused(monkeypatch, clip, tmp_path, capsys):
    """A header stating 50 fps over timestamps 1/25 s apart (the two cannot both be right)."""
    import m3c.nodes.frames as frames

    real = frames.probe_video

    def lying_probe(path):
        info = real(path)
        return type(info)(info.path, 50.0, info.width, info.height, info.frame_count_hint, info.rotation)

    monkeypatch.setattr(frames, "probe_video", lying_probe)
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path))
    assert code == 2 and "states 50.000 fps but its frame timestamps step at 25.000 fps" in err, err


@pytest.mark.parametrize("intrinsics, message", [
    (["1e12", "1e12", "160", "90"], "fx = 1e+12 px"),
    (["300", "300", "1e6", "90"], "principal point (1e+06, 90) lies outside"),
    (["0.001", "0.001", "160", "90"], "fx = 0.001 px"),
])
def test_intrinsics_of_no_camera_are_refused_unless_forced(clip, tmp_path, capsys, intrinsics, message, caplog):
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--intrinsics", *intrinsics)
    assert code == 2 and message in err and "--force-intrinsics" in err, err
    with caplog.at_level(logging.WARNING, logger="m3c.nodes.camera"):
        code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config",
                               frames_only_config(tmp_path), "--intrinsics", *intrinsics, "--force-intrinsics")
    assert code == 0, err
    assert any(message in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "ok", "--config", frames_only_config(tmp_path),
                           "--intrinsics", "300", "300", "160", "90")
    assert code == 0, err


def test_missing_device_and_checkpoint_folder_are_errors(clip, tmp_path, capsys):
    import torch

    if torch.cuda.device_count() > 7:
        pytest.skip("this machine has a cuda:7")
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--set", "settings.device=cuda:7")
    assert code == 2 and "settings.device='cuda:7'" in err and "Traceback" not in err, err
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--set", "settings.device=tpu")
    assert code == 2 and "settings.device='tpu'" in err, err
    code, _, err = run_cli(capsys, "run", clip, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--checkpoints", tmp_path / "no-such-folder")
    assert code == 2 and "no-such-folder is not a folder" in err, err
    assert not (tmp_path / "out" / "cache" / "frames").exists()


def _walker(speed: float, fps: float = 30.0, seconds: float = 3.0) -> np.ndarray:
    n = int(seconds * fps)
    joints = np.zeros((n, 24, 3))
    joints[:, :, 1] = 0.9
    joints[:, 7:12, 1] = 0.05
    joints[:, :, 2] = (speed * np.arange(n) / fps)[:, None]
    return joints


def test_faster_than_any_person_is_marked():
    fast = track_plausibility(_walker(30.0), 30.0)
    assert fast["implausible_speed"] and fast["sustained_speed_mps"] == pytest.approx(30.0, rel=1e-6)
    sprinter = track_plausibility(_walker(10.0), 30.0)
    assert not sprinter["implausible_speed"] and sprinter["sustained_speed_mps"] < MAX_HUMAN_SPEED_MPS
    # a half-second burst over the limit is not sustained
    joints = _walker(1.0)
    burst = np.zeros(len(joints))
    burst[30:45] = 20.0 / 30
    joints[:, :, 2] += np.cumsum(burst)[:, None]
    assert not track_plausibility(joints, 30.0)["implausible_speed"]
