"""Metric VO scale from the ground: synthetic scenes of known scale, and the patch VO's own map of a room."""

import numpy as np
import pytest

from m3c.vo import ground_in_camera, relative_ate, run_vo, scale_from_ground, umeyama_sim3
from m3c.vo.synthetic import ROOM_MAX, forward_trajectory, look_rotation, render_sequence

GROUND_Y = 1.5  # metric world: OpenCV-like, y down, ground plane y = GROUND_Y, cameras near y = 0
UP = np.array([0.0, -1.0, 0.0])


def _metric_cameras(T=30):
    poses = np.tile(np.eye(4), (T, 1, 1))
    for i in range(T):
        s = i / (T - 1)
        pitch = -0.25 + 0.05 * np.sin(4 * np.pi * s)  # looking down at the ground
        poses[i, :3, :3] = look_rotation(0.2 * np.sin(2 * np.pi * s), pitch, 0.03)
        poses[i, :3, 3] = [0.3 * np.sin(2 * np.pi * s), 0.05 * np.sin(6 * np.pi * s), 3.0 * s]
    return poses


def _ground_points(rng, n):
    return np.column_stack([rng.uniform(-3, 3, n), np.full(n, GROUND_Y), rng.uniform(2, 12, n)])


def _clutter(rng, n, clearance=0.0):
    """A wall beside the path and things at every height (no single height), down to `clearance` metres
    above the ground."""
    k, m = n // 2, n - n // 2
    low = GROUND_Y - clearance
    wall = np.column_stack([np.full(k, 2.0), rng.uniform(-1.0, low, k), rng.uniform(3, 10, k)])
    across = rng.uniform(-3, 3, m)
    things = np.column_stack([across, rng.uniform(0.0, min(low, GROUND_Y - 0.1), m), rng.uniform(2, 12, m)])
    return np.concatenate([wall, things])


def _to_vo(points_m, poses_m, scale, seed=3):
    """Expresses a metric scene in an arbitrary VO frame whose unit is `scale` metres."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    shift = rng.standard_normal(3)
    points_vo = (points_m @ rot.T + shift) / scale
    poses_vo = poses_m.copy()
    poses_vo[:, :3, :3] = rot @ poses_m[:, :3, :3]
    poses_vo[:, :3, 3] = (poses_m[:, :3, 3] @ rot.T + shift) / scale
    return points_vo, poses_vo


def _ground_in_cameras(poses_m):
    normals = np.einsum("tji,j->ti", poses_m[:, :3, :3], UP)  # R^T up
    heights = GROUND_Y - poses_m[:, 1, 3]
    return normals, heights


def test_recovers_scale_with_clutter_and_noise():
    rng = np.random.default_rng(0)
    poses_m = _metric_cameras()
    points_m = np.concatenate([_ground_points(rng, 300), _clutter(rng, 600)])
    points_m += 0.01 * rng.standard_normal(points_m.shape)  # 1 cm noise on every point
    true_scale = 2.7
    points_vo, poses_vo = _to_vo(points_m, poses_m, true_scale)
    normals, heights = _ground_in_cameras(poses_m)
    # The ground is known in every third frame only.
    frames = np.arange(0, len(poses_m), 3)
    scale, info = scale_from_ground(points_vo, poses_vo, normals[frames], heights[frames], frames)
    assert scale == pytest.approx(true_scale, rel=0.02), info
    assert info.reason == ""
    assert info.points > 100 and info.frames == len(frames)
    assert info.spread < 0.03
    assert info.contrast > 2.0


def test_unnormalised_normals_and_unusable_frames_are_handled():
    rng = np.random.default_rng(1)
    poses_m = _metric_cameras()
    points_vo, poses_vo = _to_vo(_ground_points(rng, 200), poses_m, 0.4)
    normals, heights = _ground_in_cameras(poses_m)
    heights[::2] = np.nan  # frames without a ground measurement are skipped
    scale, info = scale_from_ground(points_vo, poses_vo, 3.0 * normals, heights)
    assert scale == pytest.approx(0.4, rel=1e-6)
    assert info.frames == len(poses_m) // 2


@pytest.mark.parametrize("seed", range(6))
def test_no_support_without_ground_points(seed):
    # Nothing within 0.3 m of the ground. (Clutter reaching down to the ground, e.g. the feet of walls, can
    # form a peak of its own there: that is the ground's height too, within the clutter's clearance.)
    rng = np.random.default_rng(seed)
    poses_m = _metric_cameras()
    points_vo, poses_vo = _to_vo(_clutter(rng, 900, clearance=0.3), poses_m, 2.7)
    normals, heights = _ground_in_cameras(poses_m)
    scale, info = scale_from_ground(points_vo, poses_vo, normals, heights)
    assert scale is None, info
    assert info.candidates > 1000  # plenty of points below the camera, just not at one height
    assert "height" in info.reason


def test_no_support_when_nothing_is_below_the_camera():
    rng = np.random.default_rng(4)
    poses_m = _metric_cameras()
    ceiling = _ground_points(rng, 200) - [0.0, 2 * GROUND_Y, 0.0]
    points_vo, poses_vo = _to_vo(ceiling, poses_m, 1.0)
    normals, heights = _ground_in_cameras(poses_m)
    scale, info = scale_from_ground(points_vo, poses_vo, normals, heights)
    assert scale is None and info.candidates == 0
    assert "min_support" in info.reason


def test_shapes_are_checked():
    poses = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(ValueError, match=r"\(M, 3\)"):
        scale_from_ground(np.zeros((4, 2)), poses, np.zeros((3, 3)), np.ones(3))
    with pytest.raises(ValueError, match=r"\(F, 3\)"):
        scale_from_ground(np.zeros((4, 3)), poses, np.zeros((2, 3)), np.ones(3))
    with pytest.raises(ValueError, match="index"):
        scale_from_ground(np.zeros((4, 3)), poses, np.zeros((1, 3)), np.ones(1), frames=[5])


def test_ground_in_camera_heights():
    normals = np.tile([0.0, -1.0, 0.0], (3, 1))
    contacts = [np.array([[0.1, 1.6, 3.0], [0.3, 1.6, 3.5]]), np.zeros((0, 3)), np.array([[0.0, 1.2, 2.0]])]
    frames, heights = ground_in_camera(contacts, normals)
    np.testing.assert_array_equal(frames, [0, 2])
    np.testing.assert_allclose(heights, [1.6, 1.2])


def test_scale_of_the_patch_vo_map_of_a_room():
    """End to end: the VO's own map of the textured room; the floor (y = ROOM_MAX[1], world y down) is the
    ground, the walls and the far end are clutter. Truth: the similarity that aligns the VO trajectory."""
    seq = render_sequence(forward_trajectory(60), seed=0)
    result = run_vo(seq.frames, intrinsics=seq.intrinsics)
    assert relative_ate(result.world_from_cam, seq.world_from_cam) <= 0.01
    true_scale, _, _ = umeyama_sim3(result.camera_centres, seq.camera_centres)
    normals = np.einsum("tji,j->ti", seq.world_from_cam[:, :3, :3], UP)
    heights = ROOM_MAX[1] - seq.camera_centres[:, 1]
    scale, info = scale_from_ground(result.points, result.world_from_cam, normals, heights)
    assert scale == pytest.approx(true_scale, rel=0.02), info
    assert info.points >= 20
