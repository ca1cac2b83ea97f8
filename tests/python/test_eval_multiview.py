"""The calibrated multiview reference (examples/pose2sim_single_person): reading it, scoring a perfect result as
zero error, and one camera through the real pipeline."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from m3c.eval import multiview as mv

FOLDER = Path(__file__).resolve().parents[2] / "examples" / "pose2sim_single_person"
# M3C's world (y up) from the calibration's (z up).
Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


@pytest.fixture(scope="module")
def seq():
    return mv.load_multiview(FOLDER)


def test_reads_cameras_and_keypoints_that_reproject(seq):
    assert [c.name for c in seq.cameras] == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert seq.keypoints.shape == (100, 21, 3) and seq.fps == 60.0
    assert np.all(seq.feet()[:, 2] > -0.05) and np.all(seq.feet()[:, 2] < 0.4)  # standing on the floor z = 0
    for cam in seq.cameras:
        assert 1.5 < cam.centre[2] < 2.5  # cameras at head height
        rvec, _ = cv2.Rodrigues(cam.cam_from_world[:3, :3])
        uv, _ = cv2.projectPoints(
            seq.keypoints.reshape(-1, 3), rvec, cam.cam_from_world[:3, 3], cam.K, np.r_[cam.distortion, 0.0]
        )
        uv = uv.reshape(-1, 2)
        inside = (uv[:, 0] > 0) & (uv[:, 0] < cam.size[0]) & (uv[:, 1] > 0) & (uv[:, 1] < cam.size[1])
        assert inside.mean() > 0.99, cam.name


def _perfect_results(seq, cam) -> dict:
    T = seq.keypoints.shape[0]
    world_from_cam = Y_UP @ np.linalg.inv(cam.cam_from_world)
    joints = np.zeros((1, T, 24, 3))
    joints[0][:, list(mv.TRC_TO_SMPL.values())] = seq.joints() @ Y_UP[:3, :3].T
    return {
        "track_ids": np.array([4]),
        "valid": np.ones((1, T), bool),
        "frame_ids": np.arange(T),
        "world_from_cam": np.repeat(world_from_cam[None], T, 0),
        "world_joints": joints,
    }


def test_a_perfect_result_scores_zero(seq):
    views = []
    for cam in seq.cameras[:2]:
        score = mv.score_view(None, seq, cam, _perfect_results(seq, cam))
        v = score.values
        for key in (
            "camera_height_error_m",
            "tilt_error_deg",
            "ground_at_feet_error_m",
            "mpjpe",
            "pa_mpjpe",
            "pelvis_depth_error_m",
        ):
            assert v[key] == pytest.approx(0.0, abs=1e-6), key
        assert v["camera_height_pred_m"] == pytest.approx(cam.centre[2])
        views.append(score)
    assert mv.disagreement_mm(views) == pytest.approx(0.0, abs=1e-6)
    # A camera placed 0.3 m too high and a body 10 % too far are measured as such.
    cam = seq.cameras[0]
    arrays = _perfect_results(seq, cam)
    arrays["world_from_cam"][:, 1, 3] += 0.3
    arrays["world_joints"][:, :, :, 1] += 0.3
    assert mv.score_view(None, seq, cam, arrays).values["camera_height_error_m"] == pytest.approx(0.3)
    arrays = _perfect_results(seq, cam)
    centre = arrays["world_from_cam"][0, :3, 3]
    arrays["world_joints"] = centre + 1.1 * (arrays["world_joints"] - centre)
    far = mv.score_view(None, seq, cam, arrays)
    assert far.values["pa_mpjpe"] == pytest.approx(0.0, abs=1e-6) and far.values["pelvis_depth_error_m"] > 0.2
    assert mv.disagreement_mm([views[0], far]) > 100


def test_bad_folder_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="multiview reference"):
        mv.load_multiview(tmp_path)


def test_one_camera_through_the_pipeline(tmp_path):
    pytest.importorskip(
        "mediapipe", reason="the default perception backend (the perception extra) is not installed"
    )
    from m3c.body import default_body_model

    report = mv.run_multiview(
        default_body_model(),
        FOLDER,
        tmp_path,
        overrides=("frames.stop=24",),
        known_intrinsics=True,
        cameras=["cam_03"],
        show_progress=False,
    )
    view = report.views[0]
    assert not view.error, view.error
    assert view.values["frames"] >= 18
    assert np.isfinite(view.values["mpjpe"]) and view.values["pa_mpjpe"] < 150
    assert "cam_03" in report.text()
