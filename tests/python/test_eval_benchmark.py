"""The mocap benchmark: seeded generation, a noise-free pipeline that must reproduce the ground truth exactly,
the camera motions, the simulated perception errors, and a short end-to-end run."""

from dataclasses import replace

import numpy as np
import pytest

from m3c.eval import metrics as M
from m3c.eval.benchmark import BenchmarkConfig, make_sequence, run_benchmark
from m3c.eval.benchmark import _eval_tracks
from m3c.eval.evaluate import evaluate_sequence
from m3c.motion import OptimizerConfig


def project(points_in_world, world_from_cam, intrinsics):
    """The pinhole model written out here, independently of m3c.camera: (pixels (..., 2), depth (...))."""
    cam_from_world = np.linalg.inv(world_from_cam)
    xc = points_in_world @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    fx, fy, cx, cy = intrinsics
    return np.stack([fx * xc[..., 0] / xc[..., 2] + cx, fy * xc[..., 1] / xc[..., 2] + cy], -1), xc[..., 2]


PERFECT = dict(keypoint_noise_px=0.0, outlier_rate=0.0, occluded_noise_px=0.0, drop_rate=0.0, gaps_per_track=0,
               depth_bias=0.0, depth_jitter=0.0, orientation_bias_deg=0.0, orientation_jitter_deg=0.0,
               pose_bias=0.0, pose_jitter=0.0, shape_error=0.0, contact_flip_rate=0.0,
               vo_rotation_drift_deg=0.0, vo_translation_drift=0.0, vo_scale_range=(1.0, 1.0))


@pytest.fixture(scope="module")
def model(open_model):
    return open_model


@pytest.fixture(scope="module")
def clips(mocap_clips):
    return mocap_clips


def test_shipped_clips_are_plausible_motion(clips):
    assert [c.info["name"] for c in clips] == ["cmu_131_01", "cmu_01_01"]
    for clip in clips:
        assert clip.fps == 30.0 and clip.num_frames >= 240
        assert clip.body_pose.shape == (clip.num_frames, 23, 3)
        assert np.median(clip.fit_error_mm) < 15.0
        speed = np.linalg.norm(np.diff(clip.transl[:, [0, 2]], axis=0), axis=1) * clip.fps
        assert 0.3 < speed.max() < 6.0  # they move, at human speeds (m/s)


def test_generation_is_seeded(model, clips):
    config = BenchmarkConfig(num_frames=30)
    a = make_sequence(model, clips, config, 1)
    b = make_sequence(model, clips, config, 1)
    c = make_sequence(model, clips, replace(config, seed=5), 1)
    np.testing.assert_array_equal(a.cameras_vo.world_from_cam, b.cameras_vo.world_from_cam)
    for sa, sb in zip(a.simulated, b.simulated):
        np.testing.assert_array_equal(sa.keypoints, sb.keypoints)
        np.testing.assert_array_equal(sa.transl_cam, sb.transl_cam)
    assert not np.allclose(a.truth[0].transl, c.truth[0].transl)
    assert len(a.truth) == 3 and a.camera_motion == "panning"  # sequence 1: 3 people, the second motion


def test_noise_free_local_reproduces_the_ground_truth(model, clips):
    config = BenchmarkConfig(num_frames=30, **PERFECT)
    seq = make_sequence(model, clips, config, 0)  # two people, walking camera
    for sim, truth in zip(sorted(seq.simulated, key=lambda s: s.person), seq.truth):
        assert sim.detected.all() and len(sim.frames) == 30
        # Noise-free keypoints are the projected COCO-17 points of the ground truth.
        pose = np.concatenate([truth.root_orient[:, None], truth.body_pose], 1)
        kp = model.keypoints(model.coco17_regressor(), pose, truth.betas, truth.transl)
        uv, _ = project(kp[7], seq.cameras_true.world_from_cam[7], seq.cameras_true.intrinsics)
        seen = sim.keypoints[7, :, 2] > 0
        np.testing.assert_allclose(sim.keypoints[7, seen, :2], uv[seen], atol=1e-9)
    gt = _eval_tracks(model, seq.truth, seq.cameras_true.world_from_cam)
    local = _eval_tracks(model, seq.local_tracks(model), seq.cameras_vo.world_from_cam)
    result = evaluate_sequence(gt, local, seq.fps)
    assert len(result.matching.matches) == 2
    for key in ("pa_mpjpe", "mpjpe", "pve", "accel", "w_mpjpe", "wa_mpjpe", "rte"):
        assert result.mean(key) == pytest.approx(0.0, abs=1e-6), key
    # Foot sliding is not a difference: a perfect prediction slides as much as the mocap itself (under 1
    # cm/frame).
    assert 0.0 < result.mean("foot_sliding") < 10.0


def test_unknown_vo_scale_shows_in_rte_not_in_pose(model, clips):
    config = BenchmarkConfig(num_frames=30, **{**PERFECT, "vo_scale_range": (2.0, 2.0)})
    seq = make_sequence(model, clips, config, 2)  # one person, orbiting camera
    gt = _eval_tracks(model, seq.truth, seq.cameras_true.world_from_cam)
    local = _eval_tracks(model, seq.local_tracks(model), seq.cameras_vo.world_from_cam)
    result = evaluate_sequence(gt, local, seq.fps)
    assert result.mean("mpjpe") == pytest.approx(0.0, abs=1e-6)  # camera-frame bodies are exact
    assert result.mean("rte") > 1.0  # the world path is built with half-length camera translations


def test_camera_motions(model, clips):
    config = BenchmarkConfig(num_frames=40)
    paths = {}
    for index, motion in enumerate(config.camera_motions):
        seq = make_sequence(model, clips, config, index)
        assert seq.camera_motion == motion
        paths[motion] = seq.cameras_true.world_from_cam
    centres = {k: v[:, :3, 3] for k, v in paths.items()}
    assert np.ptp(centres["static"], axis=0).max() == 0 and np.ptp(paths["static"][:, :3, :3], axis=0).max() == 0
    assert np.ptp(centres["panning"], axis=0).max() < 0.05  # a hand-held camera standing still
    view = paths["panning"][:, :3, 2]  # viewing directions turn
    assert np.degrees(np.arccos(np.clip(view @ view[0], -1, 1))).max() > 5.0
    assert np.linalg.norm(centres["orbiting"][-1] - centres["orbiting"][0]) > 0.5
    assert np.linalg.norm(centres["walking"][-1] - centres["walking"][0]) > 0.2
    for world_from_cam in paths.values():  # every camera is a proper rotation, looking roughly level
        R = world_from_cam[:, :3, :3]
        np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.tile(np.eye(3), (len(R), 1, 1)), atol=1e-9)
        assert np.abs(R[:, 1, 2]).max() < 0.5


def test_simulated_perception_errors(model, clips):
    config = BenchmarkConfig(num_frames=60)
    seq = make_sequence(model, clips, config, 1)  # three people: occlusions are likely
    kp = np.concatenate([s.keypoints for s in seq.simulated])
    conf = kp[..., 2]
    assert (conf == 0).any() and (conf[conf > 0] < 1.0).all()
    assert any(not s.detected.all() for s in seq.simulated)  # gaps and drops
    # VO: unknown scale and drift; rotations stay proper.
    vo, true = seq.cameras_vo.world_from_cam, seq.cameras_true.world_from_cam
    assert not np.allclose(vo[:, :3, 3] * seq.vo_scale, true[:, :3, 3])
    ate = M.camera_ate(vo, true)
    assert 0 < np.sqrt((ate ** 2).mean()) < 100.0  # mm: drift, not garbage


def test_short_end_to_end_run(model):
    optimizer = OptimizerConfig.default()
    optimizer.stages = optimizer.stages[:3]  # the root and camera-scale stages: quick
    config = BenchmarkConfig(num_sequences=1, num_frames=30, max_people=1, optimizer=optimizer)
    report = run_benchmark(model, config)
    text = report.tables()
    for word in ("Local", "Global Opt", "Global Regr", "PA-MPJPE", "W-MPJPE100", "seq00_walking^1"):
        assert word in text
    rows = report.method_rows()
    assert rows["Local"]["pa_mpjpe"] > 0 and rows["Global Opt"]["rte"] is not None
    summary = report.summary()
    assert summary["sequences"][0]["matched"] == {"Local": 1, "Global Opt": 1}


def test_retarget_folder_caches(tmp_path, model, monkeypatch):
    import m3c.eval.retarget as retarget_module
    from m3c.eval.benchmark import retarget_folder
    from m3c.eval.retarget import RetargetedMotion

    from test_eval_retarget import TWO_JOINTS

    calls = []

    def fake_retarget(model, bvh, joint_map, config, frames):
        calls.append(frames)
        return RetargetedMotion(30.0, np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 23, 3)), np.zeros(10),
                                np.zeros(3))

    monkeypatch.setattr(retarget_module, "retarget", fake_retarget)
    monkeypatch.setattr(retarget_module, "detect_joint_map", lambda bvh: "cmu_motionbuilder")
    (tmp_path / "mocap" / "sub").mkdir(parents=True)
    (tmp_path / "mocap" / "sub" / "a.bvh").write_text(TWO_JOINTS)
    first = retarget_folder(model, tmp_path / "mocap", tmp_path / "cache")
    second = retarget_folder(model, tmp_path / "mocap", tmp_path / "cache")
    assert first == second and first[0].is_file() and first[0].parent == tmp_path / "cache"
    assert calls == [slice(1, None)]  # retargeted once; CMU files lose their added T-pose frame
    assert RetargetedMotion.load(first[0]).source.endswith("a.bvh")
    with pytest.raises(FileNotFoundError, match="no .bvh"):
        retarget_folder(model, tmp_path / "cache", tmp_path / "cache")


def test_local_ground_planes_are_the_world_ground_in_camera_coordinates(model, clips):
    """The optimizer takes each person's ground in the frame's camera coordinates (metric): with the true
    cameras the planes must map back to the world ground y = 0."""
    seq = make_sequence(model, clips, BenchmarkConfig(num_sequences=1, num_frames=30, max_people=1), 0)
    for track in seq.local_tracks(model):
        cams = seq.cameras_true.world_from_cam[track.first_frame:track.first_frame + track.num_frames]
        normal_world = np.einsum("tij,tj->ti", cams[:, :3, :3], track.ground_normal)
        np.testing.assert_allclose(normal_world, np.tile([0.0, 1.0, 0.0], (track.num_frames, 1)), atol=1e-12)
        offset_world = track.ground_offset - np.einsum("tj,tj->t", normal_world, cams[:, :3, 3])
        np.testing.assert_allclose(offset_world, 0.0, atol=1e-9)


def test_missing_vposer_weights_are_named(model, tmp_path):
    config = BenchmarkConfig(num_sequences=1, num_frames=30, max_people=1, vposer=str(tmp_path / "vposer.safetensors"))
    with pytest.raises(FileNotFoundError, match="vposer.safetensors"):
        run_benchmark(model, config)
