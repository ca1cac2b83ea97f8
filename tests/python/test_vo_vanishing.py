"""The focal length and the up direction from a scene's straight lines (m3c.vo.vanishing): a built scene of poles
and kerbs drawn at a known focal length and tilt (m3c.vo.synthetic.built_scene_edges, projected with the camera
it is compared with) is measured within 2% and half a degree; a level camera gives the up direction but no focal
length; a textureless frame, a frame under a people mask and frames that disagree give no estimate; the ground's
tilt prior reads the frames' up directions in the odometry's frame, a stray frame left out, its forward sigma
widened by the focal length's uncertainty."""

import numpy as np
import pytest

from m3c.ground import GroundParams
from m3c.ground.world_frame import dominant_ground, scene_up_prior
from m3c.vo.synthetic import built_scene_edges, look_rotation
from m3c.vo.vanishing import (SceneLineConfig, _focal_squared, _jackknife_log_sigma, _refine, agreeing_direction,
                              estimate_scene_camera, frame_vanishing_points, line_segments)

W, H = 960, 540
DIAGONAL = float(np.hypot(W, H))


def _view(focal, pitch, roll=0.0, yaw=0.2, seed=1):
    """(image, true up in the camera (OpenCV axes)); world y points down in the synthetic scene."""
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(yaw, pitch, roll)
    image = built_scene_edges(W, H, [focal, focal, W / 2, H / 2], pose, seed=seed)
    return image, pose[:3, :3].T @ np.array([0.0, -1.0, 0.0])


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("focal, pitch, roll", [(800.0, -0.2, 0.05), (1400.0, -0.14, -0.03), (900.0, 0.15, 0.02)])
def test_focal_and_up_of_a_built_scene(focal, pitch, roll):
    image, up = _view(focal, pitch, roll)
    found = frame_vanishing_points(image)
    assert found is not None and found.vertical_inliers >= 10 and found.horizontal_inliers >= 6
    assert found.focal == pytest.approx(focal, rel=0.02)
    estimate = estimate_scene_camera([image], config=SceneLineConfig(min_frames=1))
    assert _angle(estimate.up(focal), up) < 0.5
    # The up direction at another focal length is the same vanishing point seen through another camera.
    wrong = estimate.up(1.5 * focal)
    assert _angle(wrong, up) > 0.5 * abs(np.degrees(np.arctan(np.tan(pitch) * 1.5)) - np.degrees(pitch))


def _segments_towards(point, count, noise, rng):
    """Unit homogeneous lines (centred, over the diagonal) of `count` segments in the image aimed at the homogeneous
    vanishing point `point` with `noise` radians of direction error, and their lengths."""
    lines, lengths = [], []
    for middle in rng.uniform(-0.35, 0.35, (count, 2)):
        towards = point[:2] - middle * point[2]
        angle = np.arctan2(towards[1], towards[0]) + rng.normal(0.0, noise)
        half = 0.5 * rng.uniform(0.03, 0.15) * np.array([np.cos(angle), np.sin(angle)])
        line = np.cross(np.r_[middle - half, 1.0], np.r_[middle + half, 1.0])
        lines.append(line / np.linalg.norm(line))
        lengths.append(2 * np.linalg.norm(half))
    return lines, lengths


@pytest.mark.parametrize("vertical_count, horizontal_count, noise", [(15, 8, 0.003), (8, 6, 0.005), (30, 20, 0.002)])
def test_jackknife_sigma_predicts_the_focal_lengths_spread(vertical_count, horizontal_count, noise):
    """A frame's log-focal sigma (the jackknife over its supporting segments) against the spread of the focal length
    over 200 independent draws of the segments' direction noise, about the true focal length (0.9 x the diagonal,
    camera 15 degrees down)."""
    rng = np.random.default_rng(0)
    focal, pitch = 0.9, np.radians(-15.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    vanishing = []
    for direction in (rotation @ [0.0, 1.0, 0.0], rotation @ [1.0, 0.0, 0.6]):
        point = np.array([focal * direction[0], focal * direction[1], direction[2]])
        vanishing.append(point / np.linalg.norm(point))
    assert _focal_squared(*vanishing) == pytest.approx(focal ** 2)
    logs, sigmas = [], []
    for _ in range(200):
        v_lines, v_lengths = _segments_towards(vanishing[0], vertical_count, noise, rng)
        h_lines, h_lengths = _segments_towards(vanishing[1], horizontal_count, noise, rng)
        lines, lengths = np.array(v_lines + h_lines), np.array(v_lengths + h_lengths)
        is_vertical = np.arange(len(lines)) < vertical_count
        points = _refine(lines[is_vertical], lengths[is_vertical]), _refine(lines[~is_vertical], lengths[~is_vertical])
        logs.append(0.5 * np.log(_focal_squared(*points)))
        sigmas.append(_jackknife_log_sigma(lines, lengths, is_vertical, ~is_vertical, *points))
    spread = np.std(logs)
    assert abs(np.mean(logs) - np.log(focal)) < 0.3 * spread  # unbiased
    assert np.median(sigmas) == pytest.approx(spread, rel=0.25)  # measured within 8%


def test_a_frame_whose_segments_leave_the_focal_length_loose_is_left_out():
    """A still camera's frames repeat the same edges: their agreement says nothing, so one frame's own uncertainty
    is the estimate's, and frames whose segments hold the focal length loosely do not count."""
    image, _ = _view(900.0, -0.18)
    found = frame_vanishing_points(image)
    assert found.focal == pytest.approx(900.0, rel=0.02) and 0 < found.focal_sigma < 0.05
    still = estimate_scene_camera([image] * 5)
    assert still.informative and still.spread == 0.0
    assert still.log_sigma == pytest.approx(found.focal_sigma)
    assert still.summary()["log_sigma"] == still.log_sigma
    strict = estimate_scene_camera([image] * 5, config=SceneLineConfig(max_focal_log_sigma=0.5 * found.focal_sigma))
    assert strict.focal is None and not strict.informative
    assert "0 of 5 frames" in strict.reason and "5 more whose segments leave it loose" in strict.reason
    assert strict.summary()["frames"][0]["focal"] == pytest.approx(found.focal)  # still in the record
    # Two segments on a point: leaving one out leaves a single line, any point of which would do: unbounded.
    rng = np.random.default_rng(1)
    lines = rng.normal(size=(5, 3))
    lines /= np.linalg.norm(lines, axis=1, keepdims=True)
    points = _refine(lines[:3], np.ones(3)), _refine(lines[3:], np.ones(2))
    assert _jackknife_log_sigma(lines, np.ones(5), np.arange(5) < 3, np.arange(5) >= 3, *points) == np.inf


def test_level_camera_has_an_up_direction_but_no_focal_length():
    image, up = _view(1100.0, 0.0)
    found = frame_vanishing_points(image)
    assert found is not None and found.focal is None  # vertical edges parallel in the image
    estimate = estimate_scene_camera([image], config=SceneLineConfig(min_frames=1))
    assert _angle(estimate.up(1100.0), up) < 0.3
    assert not estimate.informative and "0 of 1 frames" in estimate.reason


def test_textureless_and_masked_frames_give_nothing():
    assert frame_vanishing_points(np.full((H, W), 128, np.uint8)) is None
    image, _ = _view(800.0, -0.2)
    everyone = np.ones((H, W), bool)  # a person's mask over the whole frame hides every edge
    assert len(line_segments(image)) > 20 and len(line_segments(image, everyone)) == 0
    assert frame_vanishing_points(image, everyone) is None


def test_frames_are_pooled_and_must_agree():
    views = [_view(800.0, -0.2, yaw=yaw, seed=seed)[0] for yaw, seed in ((0.0, 1), (0.1, 2), (0.2, 3), (0.3, 4),
                                                                          (0.15, 5))]
    estimate = estimate_scene_camera(views, config=SceneLineConfig(min_frames=5), frame_ids=[0, 10, 20, 30, 40])
    assert estimate.informative and estimate.focal == pytest.approx(800.0, rel=0.02)
    summary = estimate.summary(800.0)
    assert [f["frame"] for f in summary["frames"]] == [0, 10, 20, 30, 40]
    assert all(len(f["up"]) == 3 for f in summary["frames"])
    # Frames of two different cameras do not agree: no estimate, and the reason says so.
    mixed = views[:3] + [_view(1300.0, -0.15, yaw=0.1, seed=s)[0] for s in (6, 7)]
    estimate = estimate_scene_camera(mixed, config=SceneLineConfig(min_frames=5))
    assert estimate.focal is not None and not estimate.informative and "over" in estimate.reason


def test_bad_settings_and_input_are_named():
    with pytest.raises(ValueError, match="low"):
        SceneLineConfig(low=2.0, high=1.0)
    with pytest.raises(ValueError, match="frames"):
        SceneLineConfig(frames=0)
    with pytest.raises(ValueError, match="tilts"):
        SceneLineConfig(min_horizontal_tilt=80.0, max_horizontal_tilt=70.0)
    with pytest.raises(ValueError, match="at least one frame"):
        estimate_scene_camera([])
    with pytest.raises(ValueError, match="differ in size"):
        line_segments(np.zeros((H, W), np.uint8), np.zeros((10, 10), bool))
    with pytest.raises(ValueError, match="gray uint8"):
        line_segments(np.zeros((H, W, 3), np.uint8))


def _rotation(axis, degrees):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis, dtype=np.float64)).as_matrix()


def test_scene_up_prior_reads_every_frame_in_the_odometry_frame():
    true_up = np.array([0.1, -0.99, -0.05])
    true_up /= np.linalg.norm(true_up)
    cameras = np.tile(np.eye(4), (30, 1, 1))
    for t in range(30):  # a panning camera: VO frame from camera t
        cameras[t, :3, :3] = _rotation([0, 1, 0], 2.0 * t)
    frames = [{"frame": t, "up": (cameras[t, :3, :3].T @ true_up).tolist()} for t in (0, 10, 20, 29)]
    up, sideways, forward = scene_up_prior({"informative": True, "frames": frames}, cameras)
    assert _angle(up, true_up) < 1e-6 and sideways == forward == 2.0  # no spread: the floor of the prior's sigma
    # The scene's own focal length need not be informative: its up directions count at the run's focal length.
    assert _angle(scene_up_prior({"informative": False, "frames": frames}, cameras)[0], true_up) < 1e-6
    assert scene_up_prior(None, cameras) is None
    # One frame another family of edges (rotated 12 degrees) is left out...
    frames[1]["up"] = (_rotation([1, 0, 0], 12.0) @ np.asarray(frames[1]["up"])).tolist()
    assert _angle(scene_up_prior({"frames": frames}, cameras)[0], true_up) < 1e-6
    # ... but frames that disagree by halves are not a prior.
    frames[2]["up"] = (_rotation([0, 0, 1], -9.0) @ np.asarray(frames[2]["up"])).tolist()
    assert scene_up_prior({"frames": frames}, cameras) is None


def test_agreeing_direction_leaves_out_a_stray_frame_against_numpy():
    rng = np.random.default_rng(3)
    base = np.array([0.05, -0.95, -0.3])
    base /= np.linalg.norm(base)
    ups = np.array([_rotation(rng.normal(size=3) / np.sqrt(3), 0.8) @ base for _ in range(8)])
    ups[5] = _rotation([1, 0, 0], 15.0) @ base  # another family of edges
    mean, spread, kept = agreeing_direction(ups)
    assert kept.tolist() == [True] * 5 + [False] + [True] * 2
    expected = ups[kept].mean(axis=0) / np.linalg.norm(ups[kept].mean(axis=0))
    assert np.allclose(mean, expected, atol=1e-12)
    rms = np.sqrt(np.mean([np.radians(_angle(u, expected)) ** 2 for u in ups[kept]]))
    assert spread == pytest.approx(np.degrees(rms), rel=1e-6) and spread < 1.0
    assert agreeing_direction(ups[:1])[0] is None  # one frame is no agreement
    wide = np.array([_rotation([1, 0, 0], a) @ base for a in (-4.0, 0.0, 4.0)])  # all within 6 of the medoid
    mean, spread, kept = agreeing_direction(wide)
    assert mean is None and kept.all() and spread == pytest.approx(np.sqrt(32 / 3), rel=2e-3)  # RMS over 3


@pytest.mark.parametrize("pitch_degrees", [8.0, 35.0])
def test_scene_up_forward_sigma_follows_the_focal_length_uncertainty(pitch_degrees):
    """The forward sigma adds how far the up direction tilts when the focal length errs by its log-sigma,
    checked against the vanishing point re-read at a focal length exp(0.1) longer."""
    from m3c.vo.vanishing import _up_from_vertical

    focal = 900.0
    up = _rotation([1, 0, 0], pitch_degrees) @ np.array([0.0, -1.0, 0.0])  # camera looking down
    assert up[2] < 0
    vertical = np.array([up[0] / DIAGONAL, up[1] / DIAGONAL, up[2] / focal])  # its vanishing point, as stored
    assert _angle(_up_from_vertical(vertical, focal, DIAGONAL), up) < 1e-6
    moved = _angle(_up_from_vertical(vertical, focal * np.exp(0.01), DIAGONAL), up) / 0.01  # degrees per log f
    cameras = np.tile(np.eye(4), (10, 1, 1))
    frames = [{"frame": t, "up": up.tolist()} for t in (0, 5, 9)]
    _, sideways, forward = scene_up_prior({"frames": frames}, cameras, focal_log_sigma=0.1)
    assert sideways == 2.0 and forward == pytest.approx(np.hypot(2.0, 0.1 * moved), rel=0.02)
    assert scene_up_prior({"frames": frames}, cameras, focal_log_sigma=0.0)[2] == 2.0


def test_the_scene_up_holds_the_contacts_ground_where_the_feet_cannot():
    """People standing at one distance leave the ground's forward tilt free: the prior decides it."""
    rng = np.random.default_rng(0)
    normal = _rotation([1, 0, 0], 6.0) @ np.array([0.0, -1.0, 0.0])  # the ground's up, in camera 0 (y down)
    height = 1.8
    points = []
    for _ in range(60):  # feet 8 m away (+- 0.3 m), across the view, on the plane n . x + height = 0
        x, z = rng.uniform(-2, 2), 8.0 + rng.uniform(-0.3, 0.3)
        y = -(height + normal[0] * x + normal[2] * z) / normal[1]
        points.append(np.array([[x, y, z]]) * (1 + 0.05 * rng.normal()))  # depth error along the ray
    cameras = np.tile(np.eye(4), (60, 1, 1))
    tracks = [{"first_frame": 0}]
    params = GroundParams()
    with_scene, source, _, _ = dominant_ground([points], tracks, cameras, np.zeros(3), params, level=False,
                                               scene_up=(normal, 2.0, 2.0))
    assert source == "contacts" and _angle(with_scene.normal, normal) < 1.0
    camera_up, _, _, _ = dominant_ground([points], tracks, cameras, np.zeros(3), params, level=False)
    assert _angle(camera_up.normal, normal) > 2.0  # the camera's own up (the other prior) is 6 degrees off

