"""The feet's motion against the ground read from images (m3c.perception.ground_motion), against known image
shifts and analytic speeds, and its use by the kinematic contacts."""

import cv2
import numpy as np
import pytest

from m3c.perception import kinematic_contacts
from m3c.perception.contacts import KinematicContactConfig
from m3c.perception.ground_motion import GroundMotionConfig, contact_pixels, ground_flow, ground_speeds


def texture(h, w, seed=0):
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (h, w)).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), 2.0)


def shifted(image, dx, dy):
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(image, m, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REFLECT)


def test_ground_flow_recovers_the_shift_of_the_ground_and_ignores_people():
    h, w = 240, 320
    ground = texture(h, w)
    person = texture(h, w, seed=1)
    shift = np.array([3.4, -1.7])  # the ground's image motion (a camera pan)
    # A person (a box) whose pixels move differently from the ground: 9 px right.
    box = (slice(60, 200), slice(130, 190))
    people = np.zeros((h, w), bool)
    people[box] = True
    previous = ground.copy()
    previous[box] = person[box]
    current = shifted(ground, *shift)
    moved = np.zeros((h, w), bool)
    moved[60:200, 139:199] = True
    current[moved] = shifted(person, 9.0, 0.0)[moved]
    feet = np.array([[150.0, 195.0], [175.0, 198.0], [np.nan, np.nan]])
    config = GroundMotionConfig()
    flow = ground_flow(previous.astype(np.uint8), current.astype(np.uint8), feet, np.full(3, 140.0), people, config)
    np.testing.assert_allclose(flow[:2], np.tile(shift, (2, 1)), atol=0.15)
    assert np.isnan(flow[2]).all()
    # Without the people mask the person's own pixels join the samples near the box and pull the estimate off.
    unmasked = ground_flow(previous.astype(np.uint8), current.astype(np.uint8), feet[:1], np.full(1, 140.0), None,
                           config)
    assert np.linalg.norm(unmasked[0] - shift) > 2.0
    # A flat image has nothing to track: no estimate rather than a wrong one.
    flat = np.full((h, w), 100, np.uint8)
    assert np.isnan(ground_flow(flat, flat, feet[:2], np.full(2, 140.0), None, config)).all()


def test_ground_speeds_against_analytic_motion():
    fps, focal, depth = 30.0, 800.0, 4.0
    n = 20
    frames = np.arange(n)
    pan = np.array([5.0, 1.0])  # px per frame: the ground's image motion
    planted = np.array([300.0, 400.0]) + frames[:, None] * pan  # moves with the ground
    swing = np.array([200.0, 400.0]) + frames[:, None] * (pan + [12.0, 0.0])  # 12 px/frame against it
    pixels = np.stack([planted, swing], axis=1)
    flow_next = np.tile(pan, (n, 2, 1))
    depths = np.zeros((n, 2, 3))
    depths[..., 2] = depth
    speeds = ground_speeds(pixels, flow_next, frames, fps, depths, focal, GroundMotionConfig())
    np.testing.assert_allclose(speeds[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(speeds[:, 1], 12.0 * fps * depth / focal, rtol=1e-9)  # 1.8 m/s
    # Unknown ground motion (the last frame has no next frame and its previous one is known: still defined) and
    # unseen points give NaN.
    flow_next[5:, 1] = np.nan
    pixels[3, 0] = np.nan
    speeds = ground_speeds(pixels, flow_next, frames, fps, depths, focal, GroundMotionConfig())
    assert np.isnan(speeds[3, 0]) and np.isnan(speeds[6:, 1]).all()
    np.testing.assert_allclose(speeds[5, 1], 1.8, rtol=1e-9)  # from the motion into frame 5 alone
    with pytest.raises(ValueError, match="flow_next"):
        ground_speeds(pixels, flow_next[:, :1], frames, fps, depths, focal, GroundMotionConfig())


def test_contact_pixels_prefer_the_foot_points():
    keypoints = np.zeros((2, 21, 3))
    keypoints[:, 15] = [10, 20, 0.9]  # left ankle
    keypoints[:, 16] = [30, 40, 0.9]  # right ankle
    keypoints[0, 17] = [11, 25, 0.9]  # left heel
    keypoints[0, 19] = [15, 27, 0.2]  # left big toe, too unsure
    px = contact_pixels(keypoints, 0.3)
    np.testing.assert_array_equal(px[0], [[11, 25], [30, 40], [10, 20], [30, 40]])
    np.testing.assert_array_equal(px[1], [[10, 20], [30, 40], [10, 20], [30, 40]])
    coco = keypoints[:, :17].copy()
    coco[1, 16, 2] = 0.0
    px = contact_pixels(coco, 0.3)
    assert np.isnan(px[1, [1, 3]]).all() and (px[0, 1] == [30, 40]).all()
    with pytest.raises(ValueError, match="keypoints must have shape"):
        contact_pixels(np.zeros((2, 5, 3)), 0.3)


def test_ground_speeds_decide_the_contacts_in_any_camera():
    n, fps = 30, 30.0
    times = np.arange(n) / fps
    # Two feet at the same height (a moving camera's noisy frame: heights cannot tell them apart).
    rng = np.random.default_rng(0)
    points = np.zeros((n, 2, 3))
    points[..., 0] = rng.normal(scale=0.01, size=(n, 2))
    speeds = np.column_stack([np.full(n, 0.1), np.full(n, 2.0)])
    speeds[:5, 1] = np.nan  # unknown there: heights alone decide (both low: contact)
    config = KinematicContactConfig()
    prob = kinematic_contacts(points, times, [0, 1, 0], False, config, ground_speeds=speeds)
    assert (prob[:, 0] > 0.9).all()
    assert (prob[5:, 1] < 0.1).all() and (prob[:5, 1] > 0.5).all()
    # A still foot well off the ground is no contact: the height factor still rules it out.
    lifted = points.copy()
    lifted[:, 0, 1] = 0.5
    prob = kinematic_contacts(lifted, times, [0, 1, 0], False, config, ground_speeds=speeds)
    assert (prob[:, 0] < 0.1).all()
    # The threshold is the config's: a foot at exactly the threshold is at one half (times the height factor).
    at = np.full((n, 2), config.ground_speed_threshold)
    prob = kinematic_contacts(points, times, [0, 1, 0], True, config, ground_speeds=at)
    np.testing.assert_allclose(prob, 0.5, atol=0.01)
    with pytest.raises(ValueError, match="ground_speeds must have shape"):
        kinematic_contacts(points, times, [0, 1, 0], False, config, ground_speeds=speeds[:, :1])


def test_ground_speeds_undo_the_foreshortening_of_motion_along_the_ray():
    """A foot sliding on the ground straight away from a camera 1.6 m above it, seen at a grazing angle: its
    image speed at depth/focal reads far too slow; taken back onto the ground plane it reads its true speed
    (projected by a reference pinhole written out here)."""
    fps, focal, n = 30.0, 1000.0, 9
    up = np.array([0.0, -1.0, 0.0])  # OpenCV camera: y down, so the ground's normal points along -y
    speed = 1.2  # m/s along the ground, away from the camera (+z)
    t = np.arange(n) / fps
    world = np.column_stack([np.full(n, 0.4), np.full(n, 1.6), 5.0 + speed * t])  # on the plane y = 1.6
    pixels = focal * world[:, :2] / world[:, 2:] + [480.0, 270.0]
    flow_next = np.zeros((n, 1, 2))  # a static camera: the ground does not move in the image
    config = GroundMotionConfig()
    naive = ground_speeds(pixels[:, None], flow_next, np.arange(n), fps, world[:, None], focal, config)
    on_ground = ground_speeds(pixels[:, None], flow_next, np.arange(n), fps, world[:, None], focal, config, up=up)
    assert naive[n // 2, 0] < 0.4 * speed  # foreshortened
    np.testing.assert_allclose(on_ground[2:-2, 0], speed, rtol=0.03)  # line fits are exact inside the track
    # Across the view nothing is foreshortened: both readings agree.
    across = np.column_stack([0.4 + speed * t, np.full(n, 1.6), np.full(n, 5.0)])
    pixels = focal * across[:, :2] / across[:, 2:] + [480.0, 270.0]
    a = ground_speeds(pixels[:, None], flow_next, np.arange(n), fps, across[:, None], focal, config)
    b = ground_speeds(pixels[:, None], flow_next, np.arange(n), fps, across[:, None], focal, config, up=up)
    np.testing.assert_allclose(b[2:-2, 0], speed, rtol=0.03)
    np.testing.assert_allclose(a[2:-2, 0], speed, rtol=0.03)
