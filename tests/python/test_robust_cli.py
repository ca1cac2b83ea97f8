"""`m3c run` on the ordinary mistakes of issue 19: each is a one-line error with exit code 2 (bad input or
configuration, see the README's exit-code table) before anything is computed, never a traceback or a crash."""

import logging
import os

import numpy as np
import pytest
import yaml

from m3c.cli import main
from m3c.io.video import VideoWriter
from m3c.nodes.load import save_outputs
from m3c.pipeline import PipelineConfig


def write_video(path, frames):
    with VideoWriter(path, 25.0, (64, 48)) as writer:
        for i in range(frames):
            writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    return path


@pytest.fixture
def small_video(tmp_path):
    return write_video(tmp_path / "small.mp4", 6)


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def frames_only_config(tmp_path):
    path = tmp_path / "frames.yaml"
    path.write_text("nodes:\n  frames: {}\n  camera: {inputs: {video: frames.video}}\n")
    return path


@pytest.mark.parametrize("make_out, message", [
    (lambda tmp: (tmp / "file").write_text("x") and tmp / "file", "is a file, not a folder"),
    (lambda tmp: (tmp / "file").write_text("x") and tmp / "file" / "sub" / "out", "lies under"),
])
def test_out_that_is_or_lies_under_a_file(small_video, tmp_path, capsys, make_out, message):
    out = make_out(tmp_path)
    for command in (["run", small_video], ["vo", small_video]):
        code, _, err = run_cli(capsys, *command, "--out", out)
        assert code == 2 and message in err and "Traceback" not in err, err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders; the check needs a normal user")
def test_unwritable_out(small_video, tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        code, _, err = run_cli(capsys, "run", small_video, "--out", locked / "out")
        assert code == 2 and "no permission to write" in err
    finally:
        locked.chmod(0o755)


def test_out_on_a_read_only_file_system(small_video, tmp_path, capsys, monkeypatch):
    # Root passes os.access everywhere; the write probe is what notices a read-only mount (simulated here).
    import errno
    import tempfile

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out")
    assert code == 2 and "cannot write in" in err and "Read-only file system" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("setting, message", [
    ("optimize.optimizer={num_threads: 0}", "num_threads must be an integer >= 1, got 0"),
    ("optimize.optimizer={num_threads: -3}", "num_threads must be an integer >= 1, got -3"),
    ("optimize.optimizer={robust_sigma: -1}", "robust_sigma must be a finite number > 0"),
    ("optimize.optimizer={latent_pose: 3}", "latent_pose must be true or false"),
    ("perception.padding=-1000", "padding must be a finite number of pixels >= 0"),
    ("vo.options={num_threads: 0}", "num_threads must be an integer >= 1"),
])
def test_bad_settings_are_refused_before_anything_runs(small_video, tmp_path, capsys, setting, message):
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--set", setting)
    assert code == 2 and message in err, err
    assert not (tmp_path / "out").exists()


def test_one_frame_video(tmp_path, capsys):
    video = write_video(tmp_path / "one.mp4", 1)
    code, _, err = run_cli(capsys, "run", video, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path))
    assert code == 2 and "has only 1 frame" in err and "at least 2 frames" in err and "failed (" not in err
    # A range that selects one frame of a longer video says so.
    video = write_video(tmp_path / "six.mp4", 6)
    code, _, err = run_cli(capsys, "run", video, "--out", tmp_path / "out", "--config", frames_only_config(tmp_path),
                           "--frames", "2:3")
    assert code == 2 and "selects only 1 frame" in err


def test_folder_given_as_the_video(tmp_path, capsys):
    (tmp_path / "clips").mkdir()
    code, _, err = run_cli(capsys, "run", tmp_path / "clips", "--out", tmp_path / "out")
    assert code == 2 and "is a folder" in err and "not found" not in err


def test_implausible_focal_length_is_refused_unless_forced(small_video, tmp_path, capsys, caplog):
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                           frames_only_config(tmp_path), "--intrinsics", "0.001", "0.001", "32", "24")
    assert code == 2 and "fx = 0.001 px" in err and "times the image diagonal" in err
    with caplog.at_level(logging.WARNING, logger="m3c.nodes.camera"):
        code, _, _ = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                             frames_only_config(tmp_path), "--intrinsics", "0.001", "0.001", "32", "24",
                             "--force-intrinsics")
    assert code == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("fx = 0.001 px" in w and "times the image diagonal" in w for w in warnings), warnings
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="m3c.nodes.camera"):
        code, _, _ = run_cli(capsys, "run", small_video, "--out", tmp_path / "out2", "--config",
                             frames_only_config(tmp_path), "--intrinsics", "80", "80", "32", "24")
    assert code == 0 and not [r for r in caplog.records if r.levelno == logging.WARNING]


def test_person_seen_in_two_frames_is_named(small_video, tmp_path, capsys):
    # The perception outputs of a video in which one person is seen in frames 1 and 2 only.
    rows = 2
    folder = tmp_path / "perception"
    box = np.tile([10.0, 5.0, 30.0, 45.0], (rows, 1)).astype(np.float32)
    save_outputs(folder, {"tracks": {"tracks": [{
        "track_id": 7, "frame": np.array([1, 2]), "box": box, "square": box, "score": np.ones(rows, np.float32),
        "keypoints": np.ones((rows, 17, 3), np.float32), "pose": np.zeros((rows, 24, 3)),
        "betas": np.zeros((rows, 10)), "transl": np.tile([0, 0, 4.0], (rows, 1))}]}})
    config = PipelineConfig.default().to_mapping()
    config["nodes"]["perception"] = {"type": "load", "config": {"path": str(folder), "outputs": ["tracks"]}}
    for node in ("focal", "vo"):  # the nodes that hide people's masks from the odometry
        del config["nodes"][node]["inputs"]["masks"], config["nodes"][node]["inputs"]["detections"]
    path = tmp_path / "two_frames.yaml"
    path.write_text(yaml.safe_dump(config))
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config", path,
                           "--static-camera", "--no-progress")
    assert code == 2 and "id 7 in 2 frames" in err and "min_visible_frames" in err, err
    assert "no detections" not in err


def test_people_seen_too_briefly_to_track_are_named(small_video, tmp_path, monkeypatch):
    # Perception saw someone in 2 of the 6 frames but its tracker confirmed no one: the run says so instead of
    # "no detections". (The perception backend is replaced by its result, so MediaPipe is not needed.)
    from types import SimpleNamespace

    from m3c.pipeline import InputError, run_pipeline

    def fake_perception(frames, fps, size, config, progress=None, source=None):
        count = sum(1 for _ in frames)
        return SimpleNamespace(num_frames=count, tracks=[], seconds={}, merged={},
                               people_per_frame=np.array([0, 1, 1, 0, 0, 0][:count]))

    monkeypatch.setattr("m3c.perception.mediapipe_pose.mediapipe_available", lambda: True)
    monkeypatch.setattr("m3c.perception.run_perception_frames", fake_perception)
    with pytest.raises(InputError, match=r"people were seen in only 2 of 6 frame\(s\), too few for a person track"):
        run_pipeline(PipelineConfig.default(), tmp_path / "out", {"video": small_video}, targets=["perception"],
                     show_progress=False)
