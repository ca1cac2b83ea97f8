"""The default pipeline end to end on real footage: the first two seconds of the bundled example (a person walking
away from a camera that follows them), with M3C's own perception and visual odometry. Needs the optional MediaPipe
package (pip install 'm3c[perception]'), which scripts/setup.sh installs."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from m3c.cli import main
from m3c.io.results import load_results
from m3c.io.video import VideoWriter
from m3c.perception.mediapipe_pose import mediapipe_available

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
NUM_FRAMES = 48

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (pip install 'm3c[perception]')")]


@pytest.fixture(scope="module")
def example_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("example") / "out"
    code = main(["run", str(EXAMPLE), "--out", str(out), "--frames", f"0:{NUM_FRAMES}", "--no-progress", "-q"])
    assert code == 0
    return out


def test_one_walker_tracked_and_fitted(example_run):
    summary, arrays = load_results(example_run)
    assert arrays["world_joints"].shape[:2] == (1, NUM_FRAMES)
    assert arrays["visible"][0].sum() >= NUM_FRAMES - 2
    for name in ("world_joints", "world_transl", "world_from_cam", "betas"):
        assert np.isfinite(arrays[name]).all(), name
    # The optimized bodies still project onto the detected 2D keypoints.
    error = arrays["reprojection_error"][0][arrays["visible"][0]]
    assert np.median(error) < 8.0
    # Every stage ran, but those that would repeat the objective before them (no network weights here).
    assert all(stage["status"] == "ok" or (stage["status"] == "skipped" and "the same objective" in stage["message"])
               for stage in summary["optimization"]["stages"])


def test_world_is_grounded_and_camera_follows_the_walker(example_run):
    _, arrays = load_results(example_run)
    joints = arrays["world_joints"][0]  # (T, 24, 3), y up, ground y = 0
    feet = joints[:, [7, 8, 10, 11], 1]
    # The lower foot rests on the ground (ankle/foot joints sit a few cm above the sole) and the head is
    # a body height above it.
    assert 0.0 < np.median(feet.min(axis=1)) < 0.15
    assert 1.3 < np.median(joints[:, 15, 1] - feet.min(axis=1)) < 1.9
    # The camera moves forward (+z, its initial viewing direction), as does the person it follows.
    centres = arrays["world_from_cam"][:, :3, 3]
    assert centres[-1, 2] - centres[0, 2] > 0.05
    assert abs(centres[-1, 0] - centres[0, 0]) < centres[-1, 2] - centres[0, 2]
    root = arrays["world_transl"][0]
    assert root[-1, 2] - root[0, 2] > 0.05
    # The person stays in front of the camera, several metres away (the walker is ~9 m ahead in the clip).
    distance = np.linalg.norm(joints[:, 0] - centres, axis=1)
    assert 4.0 < np.median(distance) < 20.0


def test_overlay_paints_the_person_and_nothing_far_from_them(example_run):
    _, arrays = load_results(example_run)
    overlay = cv2.VideoCapture(str(example_run / "overlay.mp4"))
    source = cv2.VideoCapture(str(EXAMPLE))
    assert int(overlay.get(cv2.CAP_PROP_FRAME_COUNT)) == NUM_FRAMES
    keypoints = arrays["keypoints_2d"][0]
    for i in range(NUM_FRAMES):
        ok_a, painted = overlay.read()
        ok_b, frame = source.read()
        assert ok_a and ok_b
        if i % 12:
            continue
        changed = np.abs(painted.astype(int) - frame.astype(int)).max(axis=2) > 60
        seen = keypoints[i, :, 2] > 0.5
        (x0, y0), (x1, y1) = keypoints[i, seen, :2].min(axis=0), keypoints[i, seen, :2].max(axis=0)
        tight = changed[int(y0):int(y1), int(x0):int(x1)]
        near = np.zeros_like(changed)
        near[max(int(y0) - 40, 0):int(y1) + 40, max(int(x0) - 40, 0):int(x1) + 40] = True
        assert tight.mean() > 0.2  # the mesh covers the person
        assert changed[~near].mean() < 0.01  # and only the person


def test_video_without_people(tmp_path, capsys):
    video = tmp_path / "empty_road.mp4"
    rng = np.random.default_rng(0)
    with VideoWriter(video, 25.0, (160, 120)) as writer:
        texture = rng.integers(0, 255, (140, 180, 3), dtype=np.uint8)
        for i in range(8):
            writer.write(np.ascontiguousarray(texture[i:i + 120, i:i + 160]))
    out = tmp_path / "out"
    code = main(["run", str(video), "--out", str(out), "--no-progress", "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "no person was found in the video" in err
    assert not (out / "results.npz").exists() and not (out / "overlay.mp4").exists()


def test_odometry_fit_is_reported(example_run, capsys):
    """The odometry ran three times and kept the run that explains its measurements best; results.json and
    `m3c info` say how well each fitted (a short clip: the finished runs are compared)."""
    summary, _ = load_results(example_run)
    fit = summary["camera"]["odometry_fit"]
    assert fit["runs"] == 3 and fit["compared_after_frames"] == NUM_FRAMES
    assert fit["keyframe_rms_px"] == fit["runs_rms_px"][fit["kept"]] == min(fit["runs_rms_px"])
    assert all(0.0 < x < 1.5 for x in fit["runs_rms_px"])
    assert main(["info", str(example_run)]) == 0
    line = f"the best fit of 3 runs after {NUM_FRAMES} frames: {fit['keyframe_rms_px']:.2f} px"
    assert line in capsys.readouterr().out

