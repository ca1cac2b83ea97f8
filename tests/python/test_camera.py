"""m3c.camera, the one pinhole model of the Python side, against OpenCV's projectPoints."""

import cv2
import numpy as np

from m3c.camera import UP, look_at, project, to_camera, world_to_image


def _random_pose(rng) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
    pose[:3, 3] = rng.normal(size=3)
    return pose


def _opencv(points, world_from_cam, intrinsics):
    cam_from_world = np.linalg.inv(world_from_cam)
    rvec = cv2.Rodrigues(cam_from_world[:3, :3])[0]
    fx, fy, cx, cy = intrinsics
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, cam_from_world[:3, 3], K, None)
    return uv.reshape(-1, 2)


def test_projection_matches_opencv(rng):
    intrinsics = np.array([800.0, 780.0, 320.0, 240.0])
    for _ in range(5):
        pose = _random_pose(rng)
        points = pose[:3, 3] + (pose[:3, :3] @ np.array([0.0, 0.0, 4.0])) + rng.normal(size=(50, 3))
        uv, depth = world_to_image(points, pose, intrinsics)
        np.testing.assert_allclose(uv, _opencv(points, pose, intrinsics), atol=1e-6)
        np.testing.assert_allclose(depth, (points - pose[:3, 3]) @ pose[:3, 2], atol=1e-12)


def test_one_camera_per_row_equals_each_camera_alone(rng):
    poses = np.stack([_random_pose(rng) for _ in range(4)])
    points = rng.normal(size=(4, 7, 3)) + 5.0
    intrinsics = rng.uniform(200, 900, size=(4, 4))
    batched = project(to_camera(points, poses), intrinsics[:, None])
    for i in range(4):
        np.testing.assert_allclose(batched[i], _opencv(points[i], poses[i], intrinsics[i]), atol=1e-6)


def test_look_at_centres_the_target_with_up_pointing_up_in_the_image(rng):
    intrinsics = np.array([500.0, 500.0, 320.0, 240.0])
    for _ in range(5):
        eye, target = rng.normal(size=3) * 3, rng.normal(size=3)
        pose = look_at(eye, target)
        np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(pose[:3, :3]), 1.0)
        uv, depth = world_to_image(np.stack([target, target + 0.1 * UP]), pose, intrinsics)
        np.testing.assert_allclose(uv[0], intrinsics[2:], atol=1e-9)
        assert depth[0] > 0 and uv[1, 1] < uv[0, 1]  # image y points down, against the world's up
