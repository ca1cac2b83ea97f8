"""Patch VO accuracy on exactly rendered synthetic sequences with known poses.

Truth: the renderer's camera poses. ATE is the RMS camera-centre error after Sim(3) alignment, divided by the
true path length.
"""

import numpy as np
import pytest

from m3c.vo import VOConfig, relative_ate, run_vo, umeyama_sim3
from m3c.vo.synthetic import (ROOM_MAX, ROOM_MIN, following_occluders, forward_trajectory, render_sequence,
                              static_trajectory)


@pytest.fixture(scope="module")
def room_sequence():
    # 60 frames, 320x240, 2.5 m forward with sway and yaw: ~3 m of path.
    return render_sequence(forward_trajectory(60), seed=0)


@pytest.fixture(scope="module")
def occluded_sequence():
    poses = forward_trajectory(60)
    return render_sequence(poses, occluders=following_occluders(poses, count=2), seed=0)


def _rotation_errors_deg(estimate, truth):
    # Both expressed relative to their first camera; rotations are scale free.
    rel_est = np.linalg.inv(estimate[0]) @ estimate
    rel_true = np.linalg.inv(truth[0]) @ truth
    delta = rel_est[:, :3, :3].transpose(0, 2, 1) @ rel_true[:, :3, :3]
    cos = np.clip((np.trace(delta, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(cos))


def test_room_trajectory_within_one_percent(room_sequence):
    seq = room_sequence
    result = run_vo(seq.frames, intrinsics=seq.intrinsics)
    ate = relative_ate(result.world_from_cam, seq.world_from_cam)
    assert ate <= 0.01, f"ATE {100 * ate:.3f}% of path length"
    assert _rotation_errors_deg(result.world_from_cam, seq.world_from_cam).max() < 0.5
    assert not result.static_camera
    # Every frame was measured; the final estimate explains the measurements to sub-pixel level.
    assert np.all(result.quality["inliers"][1:] >= 20)
    assert np.median(result.quality["reprojection_rms_px"][1:]) < 0.5


def test_default_intrinsics_when_camera_is_unknown(room_sequence):
    # The renderer uses f = sqrt(W^2 + H^2) and the centre too, so leaving intrinsics out must work as well.
    seq = room_sequence
    result = run_vo(seq.frames)
    np.testing.assert_allclose(result.intrinsics, seq.intrinsics)
    assert relative_ate(result.world_from_cam, seq.world_from_cam) <= 0.01


def test_masks_reduce_error_with_moving_occluders(occluded_sequence):
    seq = occluded_sequence
    assert 0.05 < seq.masks.mean() < 0.35  # the occluders cover a real part of the image
    unmasked = run_vo(seq.frames, intrinsics=seq.intrinsics)
    masked = run_vo(seq.frames, masks=seq.masks, intrinsics=seq.intrinsics)
    # The thesis's change by itself: masks only zero the sampling gradient; measurements are not rejected.
    sampling_only = run_vo(seq.frames, masks=seq.masks, intrinsics=seq.intrinsics,
                           config=VOConfig(reject_masked=False))
    ate_unmasked = relative_ate(unmasked.world_from_cam, seq.world_from_cam)
    for name, result in (("masked", masked), ("sampling-only", sampling_only)):
        ate = relative_ate(result.world_from_cam, seq.world_from_cam)
        assert ate <= 0.01, f"{name} ATE {100 * ate:.3f}%"
        assert ate < 0.25 * ate_unmasked, f"{name} {100 * ate:.3f}% vs unmasked {100 * ate_unmasked:.3f}%"


def test_depth_initialisation_speeds_convergence(room_sequence):
    seq = room_sequence
    # Single start and a 3-iteration budget for the initial bundle adjustment: with depth-initialised patches
    # it is already near its converged cost; with constant inverse depth it is far from it.
    # Only the initialisation matters here, which happens within the first 20 frames.
    frames, depths = seq.frames[:20], seq.depths[:20]
    short = VOConfig(init_multi_start=False, init_iterations=3)
    with_depth = run_vo(frames, depths=depths, intrinsics=seq.intrinsics, config=short)
    without = run_vo(frames, intrinsics=seq.intrinsics, config=short)
    assert with_depth.stats["init_ba_initial_cost"] == pytest.approx(without.stats["init_ba_initial_cost"])
    assert with_depth.stats["init_ba_final_cost"] < 0.2 * without.stats["init_ba_final_cost"]
    # Iterations to convergence with a generous budget.
    long = VOConfig(init_multi_start=False, init_iterations=60)
    with_depth = run_vo(frames, depths=depths, intrinsics=seq.intrinsics, config=long)
    without = run_vo(frames, intrinsics=seq.intrinsics, config=long)
    assert with_depth.stats["init_ba_iterations"] < without.stats["init_ba_iterations"]


def test_depth_initialisation_reduces_error_on_a_tight_budget(room_sequence):
    """DPVO-like budget (few iterations per update, no final pass): depth-initialised patches need no
    iterations to find their depth, so the online trajectory is more accurate. The depth maps carry an unknown
    scale and 5% noise, as a monocular depth network's would."""
    seq = room_sequence
    rng = np.random.default_rng(0)
    depths = (seq.depths * 3.7 * np.exp(0.05 * rng.standard_normal(seq.depths.shape))).astype(np.float32)
    tight = VOConfig(init_multi_start=False, init_iterations=3, window_iterations=1, final_iterations=0,
                     refine_non_keyframes=False)
    with_depth = run_vo(seq.frames, depths=depths, intrinsics=seq.intrinsics, config=tight)
    without = run_vo(seq.frames, intrinsics=seq.intrinsics, config=tight)
    ate_depth = relative_ate(with_depth.world_from_cam, seq.world_from_cam)
    ate_none = relative_ate(without.world_from_cam, seq.world_from_cam)
    assert ate_depth <= 0.01
    assert ate_depth < 0.6 * ate_none, f"depth {100 * ate_depth:.3f}% vs none {100 * ate_none:.3f}%"


def test_static_camera_is_reported():
    seq = render_sequence(static_trajectory(3), seed=4)
    frames = np.concatenate([seq.frames[:1]] * 20)
    result = run_vo(frames, intrinsics=seq.intrinsics)
    assert result.static_camera
    assert "static" in result.message
    np.testing.assert_allclose(result.world_from_cam, np.tile(np.eye(4), (20, 1, 1)), atol=1e-6)


def test_static_camera_with_noise_and_a_moving_person_is_still_static():
    poses = static_trajectory(25)
    occluders = following_occluders(forward_trajectory(25, length=0.0, sway=0.0, yaw_amplitude=0.0), count=1)
    seq = render_sequence(poses, occluders=occluders, noise_sigma=1.5, seed=5)
    result = run_vo(seq.frames, masks=seq.masks, intrinsics=seq.intrinsics)
    assert result.static_camera
    np.testing.assert_allclose(result.camera_centres, 0.0, atol=1e-12)
    assert _rotation_errors_deg(result.world_from_cam, poses).max() < 0.1


def test_short_clip_initialises_with_the_frames_it_has(room_sequence):
    # Two and four frames (every third pose): fewer than init_frames keyframes, initialised at the end.
    seq = room_sequence
    frames, truth = seq.frames[:12:3], seq.world_from_cam[:12:3]
    rel_truth = (np.linalg.inv(truth[0]) @ truth)[:, :3, 3]
    for T in (2, 4):
        result = run_vo(frames[:T], intrinsics=seq.intrinsics)
        assert not result.static_camera
        est = result.camera_centres[T - 1]
        cos = est @ rel_truth[T - 1] / (np.linalg.norm(est) * np.linalg.norm(rel_truth[T - 1]))
        assert np.degrees(np.arccos(min(1.0, cos))) < 3.0



def test_non_keyframe_poses_without_refinement(room_sequence):
    """Keyframes from the bundle adjustment, the other frames only from their stored relative pose."""
    seq = room_sequence
    result = run_vo(seq.frames, intrinsics=seq.intrinsics, config=VOConfig(refine_non_keyframes=False))
    assert not result.quality["refined"].any()
    assert not result.quality["keyframe"].all()
    assert relative_ate(result.world_from_cam, seq.world_from_cam) <= 0.01


def _distance_to_room(points):
    """Distance of each point to the nearest wall, floor or ceiling of the rendered room (metres)."""
    return np.minimum(np.abs(points - ROOM_MIN), np.abs(points - ROOM_MAX)).min(axis=1)


@pytest.mark.parametrize("max_image_side", [640, 200])
def test_map_points_lie_on_the_room_and_reproject_to_their_host_pixels(room_sequence, max_image_side):
    """The exposed map, scaled by the similarity that aligns the VO trajectory onto the truth (both worlds are
    the first camera; the trajectory's rotation about its own direction is weakly determined, so the first
    true camera places the map), lies on the room's surfaces and projects through the true host camera onto
    the host pixel. At max_image_side 200 the VO works on a downscaled image (scale 0.625), so the host pixels
    must have been mapped back to input resolution."""
    seq = room_sequence
    result = run_vo(seq.frames, intrinsics=seq.intrinsics, config=VOConfig(max_image_side=max_image_side))
    assert relative_ate(result.world_from_cam, seq.world_from_cam) <= 0.01
    M = len(result.points)
    assert M >= 300
    assert result.points.shape == (M, 3) and result.point_pixels.shape == (M, 2)
    assert result.point_frames.shape == (M,) and result.point_inliers.shape == (M,)
    assert np.all(result.point_inliers >= 1)
    assert np.all(result.quality["keyframe"][result.point_frames])  # hosts are keyframes
    scale, _, _ = umeyama_sim3(result.camera_centres, seq.camera_centres)
    first = seq.world_from_cam[0]
    world = (scale * result.points) @ first[:3, :3].T + first[:3, 3]
    cam_from_world = np.linalg.inv(seq.world_from_cam[result.point_frames])
    x = np.einsum("nij,nj->ni", cam_from_world[:, :3, :3], world) + cam_from_world[:, :3, 3]
    assert np.all(x[:, 2] > 0)
    # Distance to the nearest surface relative to the distance from the host camera.
    relative = _distance_to_room(world) / np.linalg.norm(x, axis=1)
    assert np.median(relative) < 0.01 and np.quantile(relative, 0.9) < 0.03, np.quantile(relative, [0.5, 0.9])
    fx, fy, cx, cy = seq.intrinsics
    uv = np.column_stack([fx * x[:, 0] / x[:, 2] + cx, fy * x[:, 1] / x[:, 2] + cy])
    error = np.linalg.norm(uv - result.point_pixels, axis=1)
    assert np.median(error) < 0.5 and np.quantile(error, 0.9) < 1.0, np.quantile(error, [0.5, 0.9])
    assert np.all((result.point_pixels >= -0.5) & (result.point_pixels <= [319.5, 239.5]))
