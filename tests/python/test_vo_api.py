"""Patch VO API: shapes, validation messages, streaming vs batch, metrics, and the synthetic renderer."""

import numpy as np
import pytest

from m3c.vo import (VisualOdometry, VOConfig, absolute_trajectory_error, default_intrinsics, path_length,
                    relative_ate, run_vo, umeyama_sim3)
from m3c.vo.synthetic import ROOM_MAX, ROOM_MIN, RoomRenderer, forward_trajectory, render_sequence


@pytest.fixture(scope="module")
def short_sequence():
    return render_sequence(forward_trajectory(24, length=1.0), width=160, height=120, seed=3)


def _random_rotation(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


# ---- metrics ----

def test_umeyama_recovers_known_similarity(rng):
    source = rng.standard_normal((40, 3))
    rotation = _random_rotation(rng)
    target = 2.5 * source @ rotation.T + np.array([0.3, -1.0, 4.0])
    scale, r, t = umeyama_sim3(source, target)
    assert scale == pytest.approx(2.5, abs=1e-10)
    np.testing.assert_allclose(r, rotation, atol=1e-10)
    np.testing.assert_allclose(t, [0.3, -1.0, 4.0], atol=1e-10)


def test_ate_is_invariant_to_similarity_and_measures_noise(rng):
    truth = forward_trajectory(30)
    estimate = truth.copy()
    rotation = _random_rotation(rng)
    estimate[:, :3, 3] = 0.2 * truth[:, :3, 3] @ rotation.T + 5.0
    assert absolute_trajectory_error(estimate, truth) < 1e-10
    noise = rng.normal(0.0, 0.01, (30, 3))
    estimate[:, :3, 3] += 0.2 * noise @ rotation.T  # 1 cm of noise in the truth's units
    ate = absolute_trajectory_error(estimate, truth)
    assert 0.008 < ate < 0.025  # RMS of 3-d noise with 1 cm per axis is ~1.7 cm
    assert relative_ate(estimate, truth) == pytest.approx(ate / path_length(truth[:, :3, 3]))
    with pytest.raises(ValueError, match="shape"):
        umeyama_sim3(np.zeros((2, 3)), np.zeros((2, 3)))


# ---- renderer ----

def _reference_depth(world_from_cam, intrinsics, u, v):
    """Scalar ray-box intersection: the camera z of the wall hit through pixel (u, v)."""
    fx, fy, cx, cy = intrinsics
    ray_cam = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
    ray = world_from_cam[:3, :3] @ ray_cam
    centre = world_from_cam[:3, 3]
    best = np.inf
    for axis in range(3):
        for bound in (ROOM_MIN[axis], ROOM_MAX[axis]):
            if ray[axis] != 0:
                t = (bound - centre[axis]) / ray[axis]
                if t > 0:
                    best = min(best, t)
    return best


def test_renderer_depth_matches_scalar_ray_box_intersection():
    pose = forward_trajectory(10)[6]
    renderer = RoomRenderer(64, 48, supersample=1, seed=1)
    _, mask, depth = renderer.render(pose)
    assert not mask.any()
    for v in (0, 7, 24, 47):
        for u in (0, 13, 32, 63):
            assert depth[v, u] == pytest.approx(_reference_depth(pose, renderer.intrinsics, u, v), rel=1e-5)


def test_renderer_is_geometrically_consistent_between_views():
    """A wall point rendered in one view has the same brightness where it projects in another view."""
    poses = forward_trajectory(12)
    renderer = RoomRenderer(160, 120, supersample=1, seed=2)
    img_a, _, depth_a = renderer.render(poses[0])
    img_b, _, _ = renderer.render(poses[8])
    fx, fy, cx, cy = renderer.intrinsics
    diffs = []
    for v in range(10, 110, 9):
        for u in range(10, 150, 11):
            point_cam = depth_a[v, u] * np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
            world = poses[0][:3, :3] @ point_cam + poses[0][:3, 3]
            cam_b = poses[8][:3, :3].T @ (world - poses[8][:3, 3])
            ub, vb = fx * cam_b[0] / cam_b[2] + cx, fy * cam_b[1] / cam_b[2] + cy
            if 1 <= ub < 158 and 1 <= vb < 118:
                diffs.append(abs(float(img_b[int(round(vb)), int(round(ub))]) - float(img_a[v, u])))
    assert len(diffs) > 50
    # Nearest-pixel lookup on a smooth texture: small differences only.
    assert np.median(diffs) < 6.0


# ---- run_vo / VisualOdometry ----

def test_run_vo_output_layout(short_sequence):
    seq = short_sequence
    result = run_vo(seq.frames)
    T = len(seq.frames)
    assert result.world_from_cam.shape == (T, 4, 4)
    assert result.world_from_cam.dtype == np.float64
    np.testing.assert_allclose(result.world_from_cam[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(result.world_from_cam[:, 3], np.tile([0, 0, 0, 1.0], (T, 1)))
    rotations = result.world_from_cam[:, :3, :3]
    identity = np.tile(np.eye(3), (T, 1, 1))
    np.testing.assert_allclose(rotations @ rotations.transpose(0, 2, 1), identity, atol=1e-9)
    np.testing.assert_allclose(result.intrinsics, default_intrinsics(160, 120))
    np.testing.assert_allclose(result.intrinsics, [200.0, 200.0, 80.0, 60.0])
    with pytest.raises(ValueError, match="image size must be positive, got 0 x 120"):
        default_intrinsics(0, 120)
    for key in ("attempted", "tracked", "inliers", "reprojection_rms_px", "keyframe", "interpolated", "refined"):
        assert result.quality[key].shape == (T,)
    assert result.quality["keyframe"][0]
    assert np.all(result.tracking_ratio <= 1.0) and np.all(result.tracking_ratio >= 0.0)
    assert not result.static_camera
    assert result.stats["num_frames"] == T


def test_streaming_matches_batch_and_rgb_matches_gray(short_sequence):
    seq = short_sequence
    K = seq.intrinsics
    batch = run_vo(seq.frames, intrinsics=K)
    vo = VisualOdometry(intrinsics=np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]]))
    for frame in seq.frames:
        vo.add_frame(frame)
    assert vo.num_frames == len(seq.frames)
    streamed = vo.finish()
    np.testing.assert_array_equal(streamed.world_from_cam, batch.world_from_cam)
    rgb = np.repeat(seq.frames[..., None], 3, axis=-1)
    colour = run_vo(rgb, intrinsics=K)
    np.testing.assert_array_equal(colour.world_from_cam, batch.world_from_cam)


def test_config_reaches_the_core():
    config = VOConfig(patches_per_frame=40, lk_window_px=13, mask_dilation_px=2, min_gradient=1.5, seed=7)
    core = config.to_core()
    assert core.patches_per_frame == 40
    assert core.lucas_kanade.window_px == 13
    assert core.lucas_kanade.seed == 7
    assert core.lucas_kanade.sampling.mask_dilation_px == 2
    assert core.lucas_kanade.sampling.min_gradient == pytest.approx(1.5)


def test_clear_errors_for_bad_input(short_sequence):
    frames = short_sequence.frames
    with pytest.raises(ValueError, match="uint8"):
        run_vo(frames.astype(np.float32))
    with pytest.raises(ValueError, match=r"\(T, H, W\) or \(T, H, W, 3\)"):
        run_vo(frames[0])
    with pytest.raises(ValueError, match="masks must have shape"):
        run_vo(frames, masks=np.zeros((2, 120, 160), bool))
    with pytest.raises(ValueError, match="bool or uint8"):
        run_vo(frames, masks=np.zeros(frames.shape, np.float32))
    with pytest.raises(ValueError, match="depths must have shape"):
        run_vo(frames, depths=np.ones((len(frames), 10, 10), np.float32))
    with pytest.raises(ValueError, match="intrinsics"):
        run_vo(frames, intrinsics=[1.0, 2.0])
    with pytest.raises(ValueError, match="intrinsics"):
        run_vo(frames, intrinsics=[-100.0, 100.0, 80.0, 60.0])
    with pytest.raises(ValueError, match="too few frames"):
        run_vo(frames[:1])
    with pytest.raises(ValueError, match="no texture"):
        run_vo(np.full((6, 120, 160), 128, np.uint8))
    vo = VisualOdometry()
    vo.add_frame(frames[0])
    with pytest.raises(ValueError, match="first frame was 160x120"):
        vo.add_frame(frames[0][:100])


def test_video_helpers_round_trip(short_sequence, tmp_path):
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is needed for video files")
    from m3c.io.video import VideoError, probe_video, read_video
    from m3c.vo import run_vo_video

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 12.5, (160, 120))
    assert writer.isOpened()
    for frame in short_sequence.frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    info = probe_video(path)
    assert (info.width, info.height) == (160, 120)
    assert info.fps == pytest.approx(12.5)
    frames, fps = read_video(path, step=2)
    assert frames.shape == (12, 120, 160) and frames.dtype == np.uint8
    assert fps == pytest.approx(6.25)
    # Lossy MJPG, so compare loosely with what was written.
    assert np.abs(frames.astype(int) - short_sequence.frames[::2].astype(int)).mean() < 4.0
    rgb, _ = read_video(path, colour="rgb", max_frames=3)
    assert rgb.shape == (3, 120, 160, 3)
    result = run_vo_video(path, intrinsics=short_sequence.intrinsics)
    assert result.world_from_cam.shape == (24, 4, 4)
    assert result.extra["fps"] == pytest.approx(12.5)
    with pytest.raises(VideoError, match="video not found"):
        read_video(tmp_path / "missing.mp4")
    with pytest.raises(ValueError, match="colour must be one of"):
        read_video(path, colour="hsv")


def test_cli_writes_the_trajectory_with_user_permissions(short_sequence, tmp_path, capsys):
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is needed for video files")
    import os
    import stat

    from m3c.cli import main

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 12.5, (160, 120))
    for frame in short_sequence.frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    out = tmp_path / "out"
    fx, fy, cx, cy = short_sequence.intrinsics
    assert main(["vo", str(path), "--out", str(out), "--intrinsics", str(fx), str(fy), str(cx), str(cy)]) == 0
    saved = np.load(out / "camera_trajectory.npz")
    assert saved["world_from_cam"].shape == (24, 4, 4)
    np.testing.assert_allclose(saved["intrinsics"], short_sequence.intrinsics)
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE((out / "camera_trajectory.npz").stat().st_mode) == 0o666 & ~umask
    assert main(["vo", str(tmp_path / "missing.mp4"), "--out", str(out)]) == 2
    assert "video not found" in capsys.readouterr().err
