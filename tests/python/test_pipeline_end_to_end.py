"""The track-level pipeline end to end on a synthetic scene (m3c.eval.scenes): a rendered video of the true
bodies, perception and odometry outputs given through `load` nodes, and the real nodes from local tracks
through the ground, the world lift and the optimization to the result files, compared with the scene's truth."""

import json

import cv2
import numpy as np
import pytest
from pipeline_scene import scene_pipeline_yaml, write_scene_inputs

from m3c.body import default_body_model
from m3c.cli import main
from m3c.io.results import ARRAYS, SCHEMA, load_results
from m3c.motion import track_joints
from m3c.pipeline import PipelineConfig, run_pipeline

NUM_FRAMES = 30


def kabsch(source, target):
    """Rotation and translation that best map source points onto target points (no scale)."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    U, _, Vt = np.linalg.svd((source - ms).T @ (target - mt))
    d = np.sign(np.linalg.det(U @ Vt))
    R = (U @ np.diag([1.0, 1.0, d]) @ Vt).T
    return R, mt - R @ ms


def aligned_error(points, truth):
    R, t = kabsch(points, truth)
    return np.linalg.norm(points @ R.T + t - truth, axis=1).mean(), R


@pytest.fixture(scope="module")
def scene_run(tmp_path_factory):
    model = default_body_model()
    folder = tmp_path_factory.mktemp("scene")
    scene = write_scene_inputs(model, folder, num_frames=NUM_FRAMES, seed=0)
    config_path = folder / "scene.yaml"
    config_path.write_text(scene_pipeline_yaml(folder, scene.cameras_true.intrinsics))
    out = folder / "out"
    code = main(["run", str(folder / "video.mp4"), "--out", str(out), "--config", str(config_path),
                 "--no-progress", "-q"])
    assert code == 0
    return model, scene, folder, out, config_path


@pytest.mark.slow
def test_result_files_follow_the_schema(scene_run):
    model, scene, _, out, _ = scene_run
    summary, arrays = load_results(out)
    assert summary["schema"] == SCHEMA and set(arrays) == set(ARRAYS)
    P, T = 2, NUM_FRAMES
    assert arrays["world_joints"].shape == (P, T, 24, 3) and arrays["body_pose"].shape == (P, T, 23, 3)
    assert arrays["world_from_cam"].shape == (T, 4, 4) and arrays["fps"].shape == ()
    np.testing.assert_array_equal(arrays["frame_ids"], np.arange(T))
    assert summary["video"]["fps"] == pytest.approx(scene.fps)
    # every frame the container lists decodes (a cut file says so: test_robust_lying_input.py)
    assert summary["video"]["total_frames"] == summary["video"]["frames_in_container"] == T
    assert summary["video"]["truncated"] is False
    # Spans and detections: a track is valid from its first to its last detection, visible where detected.
    for p, init in enumerate(scene.init):
        detected = (init.keypoints[:, :, 2] > 0).any(axis=1)
        np.testing.assert_array_equal(arrays["visible"][p], detected)
        first, last = np.flatnonzero(detected)[[0, -1]]
        np.testing.assert_array_equal(np.flatnonzero(arrays["valid"][p]), np.arange(first, last + 1))
        assert np.isnan(arrays["world_transl"][p][~arrays["valid"][p]]).all()
        assert np.isfinite(arrays["world_joints"][p][arrays["valid"][p]]).all()
    # Camera-frame parameters are the world ones seen from each camera.
    assert summary["lift"]["method"] == "camera" and summary["optimization"]["optimized"]
    assert summary["body_model"]["name"] == model.data.name
    assert summary["backends"]["perception"]["type"] == "load"
    assert [t["id"] for t in summary["tracks"]] == [0, 1]


@pytest.mark.slow
def test_world_motion_matches_the_truth(scene_run):
    model, scene, _, out, _ = scene_run
    _, arrays = load_results(out)
    valid = arrays["valid"]
    truth = np.stack([track_joints(model, t) for t in scene.truth])
    final, R = aligned_error(arrays["world_joints"][valid].reshape(-1, 3).astype(float),
                             truth[valid].reshape(-1, 3))
    lift = np.full_like(truth, np.nan)
    for p in range(2):
        frames = np.flatnonzero(valid[p])
        pose = np.concatenate([arrays["lift_world_root_orient"][p, frames][:, None],
                               arrays["body_pose"][p, frames]], axis=1).astype(float)
        lift[p, frames] = model.joints(pose, arrays["betas"][p].astype(float),
                                       arrays["lift_world_transl"][p, frames].astype(float))
    lifted, _ = aligned_error(lift[valid].reshape(-1, 3), truth[valid].reshape(-1, 3))
    # Measured: final 0.117 m, lift 0.143 m (30 frames, seed 0); one rigid alignment for the whole clip.
    assert final < 0.16 and final < lifted
    # Gravity: the world's up axis is the truth's up axis (the ground was found and aligned to y = 0).
    assert np.degrees(np.arccos(np.clip((R @ [0, 1, 0])[1], -1, 1))) < 5.0
    ground_truth_feet = truth[..., [7, 8, 10, 11], 1]  # the scene plants the lowest foot joint at y = 0
    contact = np.stack([t.contacts for t in scene.truth]) > 0.5
    ours = arrays["world_joints"][..., [7, 8, 10, 11], 1]
    # The fitted ground lies under the soles, a few centimetres below the foot joints the scene plants at 0.
    assert abs(np.nanmean(np.where(contact & valid[..., None], ours, np.nan))
               - ground_truth_feet[contact].mean()) < 0.10
    # Keypoints: reprojection error about the scene's 2 px noise.
    assert np.nanmean(arrays["reprojection_error"]) < 4.0
    # The camera moved forward, as the truth's did, and the scale is positive.
    assert float(arrays["camera_scale"]) > 0
    travelled = arrays["world_from_cam"][-1, :3, 3] - arrays["world_from_cam"][0, :3, 3]
    assert travelled[2] > 0.3


@pytest.mark.slow
def test_videos_and_plot(scene_run):
    _, scene, folder, out, _ = scene_run
    W, H = scene.image_size
    for name, size in (("overlay.mp4", (W, H)), ("world.mp4", (960, 540))):
        cap = cv2.VideoCapture(str(out / name))
        assert cap.isOpened(), name
        count = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            assert frame.shape[:2] == (size[1], size[0])
            count += 1
        cap.release()
        assert count == NUM_FRAMES, name
    # The overlay changes the frame where the bodies are (coloured meshes over the rendered people).
    source, overlay = cv2.VideoCapture(str(folder / "video.mp4")), cv2.VideoCapture(str(out / "overlay.mp4"))
    _, a = source.read()
    _, b = overlay.read()
    changed = np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > 60
    assert 0.01 < changed.mean() < 0.5
    plot = cv2.imread(str(out / "camera_trajectory.png"))
    assert plot is not None and plot.shape[0] > 300


@pytest.mark.slow
def test_rerun_is_cached_and_identical(scene_run, capsys):
    _, _, folder, out, config_path = scene_run
    before = {name: (out / name).read_bytes() for name in ("results.npz", "results.json")}
    report = run_pipeline(PipelineConfig.from_yaml(config_path), out, {"video": folder / "video.mp4"},
                          show_progress=False)
    assert report.ran() == []
    assert {name: (out / name).read_bytes() for name in before} == before
    # A changed optimizer setting re-runs the optimization and what follows, nothing before it.
    changed = PipelineConfig.from_yaml(config_path).with_overrides({"optimize.enabled": False})
    report = run_pipeline(changed, out, {"video": folder / "video.mp4"}, targets=["results"], show_progress=False)
    assert set(report.ran()) == {"optimize", "results"}
    assert set(report.status()) == set(report.ran()) | {"frames", "camera", "perception", "vo", "local_tracks",
                                                         "scale", "ground", "lift"}
    assert not json.loads((out / "results.json").read_text())["optimization"]["optimized"]
    assert main(["info", str(out)]) == 0
    assert "no optimization" in capsys.readouterr().out


@pytest.mark.slow
def test_exported_priors_are_used_from_the_models_folder(scene_run, tmp_path):
    """humor.safetensors under $M3C_MODELS/export (here settings.models_dir) switches the motion prior on: the
    optimization re-runs with the term; an explicit path that does not exist is an error before anything runs."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel
    from m3c.pipeline import PipelineError

    _, _, folder, out, config_path = scene_run
    torch.manual_seed(0)
    export_weights(tmp_path / "export", humor=HumorModel().eval(), dtype="float64")
    base = PipelineConfig.from_yaml(config_path)
    missing = base.with_overrides({"optimize.motion_prior": str(tmp_path / "nope.safetensors")})
    with pytest.raises(PipelineError, match="nope.safetensors does not exist; export it"):
        run_pipeline(missing, out, {"video": folder / "video.mp4"}, targets=["results"], show_progress=False)
    with_prior = base.with_overrides({"settings.models_dir": str(tmp_path)})
    report = run_pipeline(with_prior, out, {"video": folder / "video.mp4"}, targets=["results"], show_progress=False)
    assert {"optimize", "results"} <= set(report.ran())  # (the lift reads the models folder too)
    stages = json.loads((out / "results.json").read_text())["optimization"]["stages"]
    motion = next(s for s in stages if s["name"] == "motion_prior")
    assert "motion_prior" in motion["terms"] and "motion_prior unavailable" not in motion["message"], motion
