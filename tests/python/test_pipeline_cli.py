"""`m3c run/info/graph/config` on bad inputs: clear errors, exit codes a script can act on, and no partial result
files."""

import numpy as np
import pytest
import yaml

from m3c.cli import main
from m3c.io.video import VideoWriter
from m3c.nodes.load import save_outputs
from m3c.pipeline import PipelineConfig

RESULT_FILES = ("results.npz", "results.json", "overlay.mp4", "world.mp4", "camera_trajectory.png")


@pytest.fixture
def small_video(tmp_path):
    path = tmp_path / "small.mp4"
    with VideoWriter(path, 25.0, (64, 48)) as writer:
        for i in range(6):
            writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    return path


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_no_results(out):
    assert not any((out / name).exists() for name in RESULT_FILES)


def test_missing_video(tmp_path, capsys):
    code, _, err = run_cli(capsys, "run", tmp_path / "nope.mp4", "--out", tmp_path / "out")
    assert code == 2 and "video file not found" in err and "nope.mp4" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content", [b"", b"this is not a video" * 100])
def test_unreadable_video(tmp_path, capsys, content):
    video = tmp_path / "bad.mp4"
    video.write_bytes(content)
    code, _, err = run_cli(capsys, "run", video, "--out", tmp_path / "out")
    assert code == 2
    assert "cannot open" in err or "no decodable frames" in err
    assert not (tmp_path / "out").exists()


def test_video_with_zero_frames(tmp_path, capsys):
    video = tmp_path / "empty.mp4"
    with VideoWriter(video, 25.0, (64, 48)):
        pass  # a valid container holding no frame
    code, _, err = run_cli(capsys, "run", video, "--out", tmp_path / "out")
    assert code == 2
    assert "no decodable frames" in err or "cannot open" in err
    assert not (tmp_path / "out").exists()


def test_default_pipeline_names_a_missing_perception_backend(small_video, tmp_path, capsys, monkeypatch):
    # Without MediaPipe the default perception cannot run: the run stops before anything runs and says what to
    # install; nothing is written.
    monkeypatch.setattr("m3c.perception.mediapipe_pose.mediapipe_available", lambda: False)
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out")
    assert code == 3
    assert "node 'perception'" in err and "pip install 'm3c[perception]'" in err
    assert not (tmp_path / "out").exists()


def test_unknown_perception_estimator(small_video, tmp_path, capsys):
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--set",
                           "perception.estimators={detector: nope}")
    assert code == 2 and "no detector estimator named 'nope'" in err and "available:" in err
    assert not (tmp_path / "out").exists()


def frames_only_config(tmp_path):
    path = tmp_path / "frames.yaml"
    path.write_text("nodes:\n  frames: {}\n  camera: {inputs: {video: frames.video}}\n")
    return path


def test_frame_range_outside_the_video(small_video, tmp_path, capsys):
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                           frames_only_config(tmp_path), "--frames", "100:200")
    assert code == 2 and "selects no frames" in err and "6 frames" in err
    assert not (tmp_path / "out").exists()
    code, out, _ = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                           frames_only_config(tmp_path), "--frames", "2:5", "--intrinsics", "50", "50", "32", "24")
    assert code == 0 and "2 node(s) ran" in out


def test_horizontal_field_of_view_gives_the_focal_length(small_video, tmp_path, capsys):
    """--hfov 90 on a 64-pixel-wide video: focal 32 px (half the width over tan 45 degrees), the centre as the
    principal point, and the camera counts as given (the focal search leaves it alone)."""
    from m3c.pipeline.cache import Cache

    code, _, _ = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                         frames_only_config(tmp_path), "--hfov", "90")
    assert code == 0
    (entry,) = (tmp_path / "out" / "cache" / "camera").iterdir()
    camera = Cache(tmp_path / "out" / "cache").load("camera", entry.name)["camera"]
    np.testing.assert_allclose(camera["intrinsics"], [32.0, 32.0, 32.0, 24.0])
    assert camera["source"] == "given"


def test_slow_motion_flag_sets_real_time(small_video, tmp_path, capsys):
    """--slow-motion 4 on a 25 fps video: the frames node gives 100 fps of real time, times a quarter of the file's."""
    from m3c.pipeline.cache import Cache

    code, _, _ = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                         frames_only_config(tmp_path), "--slow-motion", "4")
    assert code == 0
    (entry,) = (tmp_path / "out" / "cache" / "frames").iterdir()
    video = Cache(tmp_path / "out" / "cache").load("frames", entry.name)["video"]
    assert video["fps"] == pytest.approx(100.0) and video["playback_fps"] == pytest.approx(25.0)
    np.testing.assert_allclose(video["times"], np.arange(6) / 100.0, atol=1e-6)


@pytest.mark.parametrize("argv, message", [
    (["--intrinsics", "0", "50", "32", "24"], "fx, fy > 0"),
    (["--hfov", "0.5"], "hfov must be the horizontal field of view in degrees"),
    (["--hfov", "60", "--intrinsics", "50", "50", "32", "24"], "not both"),
    (["--set", "camera.nope=1"], "unknown setting"),
    (["--set", "ghost.x=1"], "no node named 'ghost'"),
    (["--frames", "5:2"], "bad frame range"),
    (["--slow-motion", "0"], "frames.slow_motion must be a number > 0"),
])
def test_bad_options(small_video, tmp_path, capsys, argv, message):
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--config",
                           frames_only_config(tmp_path), *argv)
    assert code == 2 and message in err, err
    assert not (tmp_path / "out").exists()


def test_missing_body_model_file(small_video, tmp_path, capsys):
    # The default pipeline reads the body model: its file is checked before anything runs.
    code, _, err = run_cli(capsys, "run", small_video, "--out", tmp_path / "out", "--body-model",
                           tmp_path / "SMPL_NEUTRAL.pkl")
    assert code == 2 and "body model file not found" in err
    assert not (tmp_path / "out").exists()


def test_video_with_no_people_given_as_perception_outputs(small_video, tmp_path, capsys):
    folder = tmp_path / "perception"
    save_outputs(folder, {"tracks": {"tracks": []}})
    config = PipelineConfig.default().to_mapping()
    config["nodes"]["perception"] = {"type": "load", "config": {"path": str(folder), "outputs": ["tracks"]}}
    for node in ("focal", "vo"):  # the nodes that hide people's masks from the odometry
        del config["nodes"][node]["inputs"]["masks"], config["nodes"][node]["inputs"]["detections"]
    path = tmp_path / "no_people.yaml"
    path.write_text(yaml.safe_dump(config))
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "run", small_video, "--out", out, "--config", path, "--static-camera")
    assert code == 2 and "no person was found in the video" in err
    assert_no_results(out)
    assert not list((out / "cache").glob("*/.tmp-*"))


def test_info_and_graph_and_config(tmp_path, capsys):
    code, _, err = run_cli(capsys, "info", tmp_path)
    assert code == 2 and "holds no M3C results" in err
    code, out, _ = run_cli(capsys, "graph")
    assert code == 0 and out.startswith("digraph m3c {") and '"optimize" -> "results"' in out
    code, out, _ = run_cli(capsys, "config")
    assert code == 0 and PipelineConfig.from_yaml(out).to_mapping() == PipelineConfig.default().to_mapping()
