"""m3c.camera.WorldCameras, the pipeline's cameras in the world with their visual-odometry scale: its metric
cameras against an independent 4 x 4 construction (a similarity applied to the VO poses, then the ground's rigid
world_from_vo), the windowed optimizer's blend of its windows' metric cameras reproduced by per-frame scales and
offsets, the optimizer's round trip, and bad input named."""

import numpy as np
import pytest
from m3c.camera import WorldCameras
from m3c.motion import Cameras
from m3c.motion.optimize import WorldResult
from m3c.motion.windows import WindowedResult, blended_scale_and_offset, window_ranges, window_weights
from scipy.spatial.transform import Rotation


def vo_poses(T: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=0.5, size=(T, 3))).as_matrix()
    poses[:, :3, 3] = rng.normal(scale=3.0, size=(T, 3))
    return poses


def similarity(scale: float, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """x -> scale * x + offset as a 4 x 4 matrix."""
    out = np.diag([scale, scale, scale, 1.0])
    out[:3, 3] = offset
    return out


def metric(poses: np.ndarray, scale: float, offset=(0.0, 0.0, 0.0), world_from_vo=None) -> np.ndarray:
    """Independent reference: the poses' frame grown by the similarity (the camera's own axes stay unit length, so
    the pose is conjugated: S P S0^-1 with S0 the scale alone), then moved rigidly into the world."""
    world_from_vo = np.eye(4) if world_from_vo is None else world_from_vo
    unscale = np.diag([1 / scale, 1 / scale, 1 / scale, 1.0])
    return np.stack([world_from_vo @ similarity(scale, offset) @ p @ unscale for p in poses])


def test_metric_cameras_match_a_4x4_composition():
    T, scale = 12, 2.7
    poses = vo_poses(T)
    world_from_vo = np.eye(4)
    world_from_vo[:3, :3] = Rotation.from_rotvec([0.3, -1.1, 0.2]).as_matrix()
    world_from_vo[:3, 3] = [0.4, 1.6, -2.0]  # metres
    cams = WorldCameras.from_vo(poses, scale, world_from_vo)
    np.testing.assert_allclose(cams.world_from_cam(), metric(poses, scale, world_from_vo=world_from_vo), atol=1e-12)
    # The rotations do not depend on the scale; the VO-unit poses are the metric ones at scale 1.
    np.testing.assert_allclose(cams.rotation, world_from_vo[:3, :3] @ poses[:, :3, :3], atol=1e-15)
    np.testing.assert_allclose(WorldCameras(cams.rotation, cams.centre_vo, 1.0).world_from_cam(),
                               cams.world_from_cam_vo(), atol=0)
    # Without a world frame: the VO frame in metres, the translations times the scale and nothing else.
    in_vo = WorldCameras.from_vo(poses, scale).world_from_cam()
    np.testing.assert_array_equal(in_vo[:, :3, :3], poses[:, :3, :3])
    np.testing.assert_array_equal(in_vo[:, :3, 3], scale * poses[:, :3, 3])
    # An offset (metres) adds after the scale.
    offset = np.array([0.5, -0.2, 1.0])
    np.testing.assert_allclose(WorldCameras.from_vo(poses, scale, offset=offset).world_from_cam(),
                               metric(poses, scale, offset), atol=1e-12)


def test_the_windowed_blend_of_metric_cameras_is_a_per_frame_scale_and_offset():
    T = 50
    poses = vo_poses(T, seed=1)
    ranges = window_ranges(T, 24, 10)
    weights = window_weights(ranges, T)
    assert len(ranges) == 3
    scales = np.array([1.9, 2.2, 2.05])
    offsets = np.array([[0.0, 0.1, 0.0], [0.3, -0.2, 0.1], [-0.1, 0.0, 0.4]])
    # Reference: every window's own metric cameras, their centres blended linearly frame by frame.
    blended = np.zeros((T, 3))
    for k, (start, stop) in enumerate(ranges):
        window = metric(poses[start:stop], scales[k], offsets[k])
        blended[start:stop] += weights[k, start:stop, None] * window[:, :3, 3]
    frame_scale, frame_offset = blended_scale_and_offset(weights, scales, offsets)
    assert frame_scale.shape == (T,) and frame_offset.shape == (T, 3)
    cams = WorldCameras.from_vo(poses, frame_scale, offset=frame_offset).world_from_cam()
    np.testing.assert_allclose(cams[:, :3, 3], blended, atol=1e-12)
    np.testing.assert_array_equal(cams[:, :3, :3], poses[:, :3, :3])
    # Where one window alone holds a frame, its camera is exactly that window's.
    alone = weights.max(axis=0) == 1.0
    np.testing.assert_array_equal(cams[alone, :3, 3], blended[alone])
    # The windowed result hands the same cameras on.
    result = WindowedResult([], 2.0, np.zeros(3), [], False, [], frame_scale, frame_offset, [])
    np.testing.assert_array_equal(result.world_cameras(Cameras(poses, np.ones(4))).world_from_cam(), cams)


def test_the_optimizer_round_trip_applies_the_scale_once():
    """Lift -> optimizer input (VO units) -> optimised cameras: the optimizer's scale and offset replace the lift's,
    and at the lift's own scale the cameras come back as the lift had them."""
    poses = vo_poses(8, seed=2)
    world_from_vo = np.eye(4)
    world_from_vo[:3, 3] = [0.0, 1.5, 0.0]
    lifted = WorldCameras.from_vo(poses, 2.5, world_from_vo)
    cameras = Cameras.from_world(lifted, np.array([500.0, 500.0, 320.0, 240.0]), static=False)
    assert cameras.initial_scale == 2.5
    same = WorldResult([], 2.5, np.zeros(3), [], False).world_cameras(cameras)
    np.testing.assert_allclose(same.world_from_cam(), lifted.world_from_cam(), atol=1e-12)
    moved = WorldResult([], 3.0, np.array([0.1, 0.0, -0.2]), [], False).world_cameras(cameras)
    expected = metric(poses, 3.0, [0.1, 1.5 * 3.0 / 2.5, -0.2], world_from_vo=np.eye(4))
    expected[:, :3, :3] = world_from_vo[:3, :3] @ poses[:, :3, :3]
    np.testing.assert_allclose(moved.world_from_cam(), expected, atol=1e-12)
    with pytest.raises(ValueError, match="one scale and no offset"):
        Cameras.from_world(moved, np.ones(4))
    # The fields travel between nodes as a dict and come back equal.
    again = WorldCameras(**lifted.as_dict())
    np.testing.assert_array_equal(again.world_from_cam(), lifted.world_from_cam())


def test_bad_input_is_named():
    poses = vo_poses(5)
    rotation, centre = poses[:, :3, :3], poses[:, :3, 3]
    with pytest.raises(ValueError, match=r"rotation must have shape \(T, 3, 3\)"):
        WorldCameras(rotation[:, :2], centre, 1.0)
    with pytest.raises(ValueError, match=r"centre_vo must have shape \(T=5, 3\)"):
        WorldCameras(rotation, centre[:4], 1.0)
    with pytest.raises(ValueError, match=r"one value or one per frame \(T=5,\)"):
        WorldCameras(rotation, centre, np.ones(4))
    with pytest.raises(ValueError, match=r"offset \(metres\) must have shape \(3,\) or \(T=5, 3\)"):
        WorldCameras(rotation, centre, 1.0, np.zeros((5, 2)))
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="camera scale .* must be finite and > 0"):
            WorldCameras(rotation, centre, bad)
        with pytest.raises(ValueError, match="camera scale .* must be finite and > 0"):
            WorldCameras.from_vo(poses, bad, np.eye(4))  # checked before it divides the world's origin
    with pytest.raises(ValueError, match="camera scale .* must be finite and > 0"):
        WorldCameras(rotation, centre, np.array([1.0, 2.0, 0.0, 1.0, 1.0]))
    nan_centre = centre.copy()
    nan_centre[2, 1] = np.nan
    with pytest.raises(ValueError, match="centre_vo must be finite, got 1 non-finite"):
        WorldCameras(rotation, nan_centre, 1.0)
    with pytest.raises(ValueError, match=r"vo_world_from_cam must have shape \(T, 4, 4\)"):
        WorldCameras.from_vo(poses[:, :3], 1.0)
    with pytest.raises(ValueError, match=r"world_from_vo must be a finite \(4, 4\) matrix"):
        WorldCameras.from_vo(poses, 1.0, np.eye(3))
    cams = WorldCameras(rotation, centre, 2.0)
    with pytest.raises(ValueError, match="read-only"):
        cams.centre_vo[0, 0] = 1.0  # frozen: what a node hands on cannot change under the next one
