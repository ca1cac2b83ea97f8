"""Kinematic contacts against the synthetic walkers' true contacts (m3c.eval.scenes), and their use by the
ground stage."""

import numpy as np
import pytest
from m3c.body import default_body_model
from m3c.body.transform import facing_directions
from m3c.eval.scenes import make_scene
from m3c.ground import estimate_ground_planes
from m3c.motion import track_joints
from m3c.perception import contact_track, create, estimate_up, kinematic_contacts
from m3c.perception.contacts import contact_rest_heights, local_velocities
from scipy.spatial.transform import Rotation


@pytest.fixture(scope="module")
def model():
    return default_body_model()


@pytest.fixture(scope="module")
def scene(model):
    return make_scene(model, num_people=2, num_frames=120, fps=30.0, seed=3)


def per_foot(c):
    """(n, 4) over CONTACT_JOINTS (ankles 7, 8; feet 10, 11) -> (n, 2) left/right foot in contact."""
    return np.stack([c[:, [0, 2]].max(1), c[:, [1, 3]].max(1)], 1) > 0.5


def test_contacts_agree_with_the_true_stance_foot(model, scene):
    rng = np.random.default_rng(0)
    estimator = create("contacts", "kinematic")
    for truth in scene.truth:
        joints = track_joints(model, truth)
        # A monocular fit's errors: 5 mm per joint, and 3 cm of whole-body jitter mostly along the camera ray.
        noisy = (joints + 0.005 * rng.normal(size=joints.shape) +
                 0.03 * rng.normal(size=(len(joints), 1, 1)) * np.array([0.3, 0.2, 1.0]))
        # The synthetic walkers plant the lowest joint itself on the ground (not the sole): no rest heights.
        c = estimator.estimate(noisy, scene.fps, np.array([0.0, 1.0, 0.0]), True)
        assert c.shape == (len(joints), 4) and ((c >= 0) & (c <= 1)).all()
        agreement = (per_foot(c) == per_foot(truth.contacts)).mean()
        assert agreement >= 0.85, agreement
        # Heights alone (a moving camera's frame without the facing rule) still see the lowest foot, but not when
        # it is lifting off.
        heights_only = create("contacts", "kinematic", {"facing_speed_threshold": None}).estimate(
            noisy, scene.fps, np.array([0.0, 1.0, 0.0]), False)
        assert (per_foot(heights_only) == per_foot(truth.contacts)).mean() >= 0.6


def test_up_from_the_spine_and_local_velocities(model, scene):
    joints = track_joints(model, scene.truth[0])
    assert np.degrees(np.arccos(estimate_up(joints) @ [0, 1, 0])) < 10
    # Velocities of a line are exact, also with uneven frame times.
    times = np.array([0.0, 0.1, 0.15, 0.4, 0.5, 0.9])
    points = np.array([0.2, -1.0, 3.0]) * times[:, None, None] + np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(local_velocities(points, times, 0.2), np.tile([0.2, -1.0, 3.0], (6, 1, 1)), atol=1e-12)


def test_contact_points_feed_the_ground_stage(model):
    # Two people standing on the plane y = 0.3 (soles on it), swaying their arms, seen for 40 frames. (The
    # synthetic walkers' stance feet are tilted with the leg, so their soles do not lie on the ground.)
    rng = np.random.default_rng(5)
    n, fps, floor = 40, 30.0, 0.3
    rest = model.forward(np.zeros((1, 24, 3)), np.zeros(model.num_betas))
    contact_tracks = []
    for person in range(2):
        pose = np.zeros((n, 24, 3))
        pose[:, 0, 1] = rng.uniform(-np.pi, np.pi)  # facing anywhere (yaw about y)
        pose[:, 16, 2] = -1.2 + 0.3 * np.sin(np.arange(n) / 5.0)  # arms down, swaying
        pose[:, 17, 2] = 1.2 - 0.3 * np.sin(np.arange(n) / 5.0)
        transl = np.tile([1.5 * person, floor - rest.vertices[0, :, 1].min(), 4.0], (n, 1))
        joints = model.joints(pose, np.zeros(model.num_betas), transl)
        contacts = create("contacts", "kinematic").estimate(joints, fps, None, True, None,
                                                            contact_rest_heights(model))
        assert (contacts > 0.5).mean() > 0.9  # standing still: feet in contact
        ct = contact_track(model, np.arange(n), pose, np.zeros(model.num_betas), transl, contacts)
        assert all(len(p) > 0 and f.all() for p, f in zip(ct.points, ct.is_foot))
        assert all(np.abs(p[:, 1] - floor).max() < 0.03 for p in ct.points)  # sole vertices only
        contact_tracks.append(ct)
    for person, plane in enumerate(estimate_ground_planes(contact_tracks, up=np.array([0.0, 1.0, 0.0]))):
        assert plane.valid.all()
        angles = np.degrees(np.arccos(np.clip(plane.normal @ [0, 1, 0], -1, 1)))
        assert angles.max() < 3.0
        # The true floor under the person lies on the estimated plane (normal . x + offset = 0).
        under_feet = np.array([1.5 * person, floor, 4.0])
        np.testing.assert_allclose(plane.normal @ under_feet + plane.offset, 0.0, atol=0.01)


def test_rest_heights_and_errors(model):
    rest = contact_rest_heights(model)
    assert rest.shape == (4,) and (rest > 0).all() and rest[0] > rest[2]  # ankles sit above the toe bases
    with pytest.raises(ValueError, match="strictly increasing"):
        kinematic_contacts(np.zeros((3, 4, 3)), np.array([0.0, 0.0, 1.0]), [0, 1, 0])
    with pytest.raises(ValueError, match="NaN"):
        kinematic_contacts(np.full((2, 4, 3), np.nan), np.array([0.0, 1.0]), [0, 1, 0])
    with pytest.raises(ValueError, match="joints must have shape"):
        create("contacts", "kinematic").estimate(np.zeros((5, 17, 3)), 30.0)


def test_facing_rule_sees_the_stance_foot_in_a_moving_camera(model, scene):
    """In a moving camera's frame, a foot moving forward relative to the body is swinging: the rule beats heights
    alone on the walkers, and a camera that translates and turns (yaw) under the people does not change it."""
    rng = np.random.default_rng(1)
    up = np.array([0.0, 1.0, 0.0])
    facing_rule = create("contacts", "kinematic", {"facing_speed_threshold": 0.4})
    heights = create("contacts", "kinematic", {"facing_speed_threshold": None})
    for truth in scene.truth:
        joints = track_joints(model, truth)
        noisy = (joints + 0.005 * rng.normal(size=joints.shape) +
                 0.03 * rng.normal(size=(len(joints), 1, 1)) * np.array([0.3, 0.2, 1.0]))
        c = facing_rule.estimate(noisy, scene.fps, up, False)
        agreement = (per_foot(c) == per_foot(truth.contacts)).mean()
        baseline = (per_foot(heights.estimate(noisy, scene.fps, up, False)) == per_foot(truth.contacts)).mean()
        assert agreement >= 0.85 and agreement > baseline + 0.025, (agreement, baseline)
        # The same people seen from a camera that moves along a curve and turns about the vertical.
        n = len(joints)
        yaw = np.linspace(0.0, 0.8, n)
        R = np.stack([np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]) for a in yaw])
        path = np.stack([np.linspace(0, 4, n), np.zeros(n), 0.5 * np.sin(np.linspace(0, 3, n))], 1)
        moved = np.einsum("nij,nkj->nki", R, noisy - path[:, None])
        assert (per_foot(facing_rule.estimate(moved, scene.fps, up, False)) == per_foot(c)).mean() >= 0.97
        # For the ground, heights alone, whatever the rule for planted feet.
        np.testing.assert_array_equal(facing_rule.estimate(noisy, scene.fps, up, False, for_ground=True),
                                      heights.estimate(noisy, scene.fps, up, False))


def test_facing_directions_follow_the_root_rotation(model):
    angles = np.radians([0.0, 35.0, 90.0, 200.0])
    pose = np.zeros((len(angles), 24, 3))
    pose[:, 0] = Rotation.from_euler("y", angles[:, None]).as_rotvec()
    joints = model.joints(pose, np.zeros(model.num_betas))
    expected = Rotation.from_euler("y", angles[:, None]).apply([0.0, 0.0, 1.0])  # the rest pose faces +z
    np.testing.assert_allclose(facing_directions(joints, [0.0, 1.0, 0.0]), expected, atol=1e-9)


def test_depth_jitter_of_a_still_camera_defeats_3d_speeds_but_not_the_facing_rule(model, scene):
    """Why perception never passes ground_static, even for a still camera: a monocular fit's depth jitters from
    frame to frame (the whole body slides along the camera rays, its image unchanged; on the basketball clip a
    standing man's feet at 10 m move 1.5 m/s median in 3D, 0.08 m/s across the rays). The walkers seen from a still
    camera 8 m away with 2% of depth jitter (16 cm): 3D foot speeds miss most planted feet, the moving camera's rule (heights
    and motion relative to the body) keeps them."""
    rng = np.random.default_rng(2)
    up = np.array([0.0, 1.0, 0.0])
    estimator = create("contacts", "kinematic")
    for truth in scene.truth:
        joints = track_joints(model, truth)
        seen = joints + np.array([0.0, -1.5, 8.0]) - joints[:, :1].mean(axis=0)  # camera frame, y up
        jittered = seen * (1.0 + 0.02 * rng.normal(size=(len(seen), 1, 1)))  # along the rays: same image
        true_feet = per_foot(truth.contacts)
        speeds = (per_foot(estimator.estimate(jittered, scene.fps, up, True)) == true_feet).mean()
        facing = (per_foot(estimator.estimate(jittered, scene.fps, up, False)) == true_feet).mean()
        clean = (per_foot(estimator.estimate(seen, scene.fps, up, True)) == true_feet).mean()
        assert clean >= 0.85 and facing >= 0.85 and speeds < 0.7 and facing > speeds + 0.15, (clean, facing, speeds)


def test_steady_depth_keeps_the_root_in_the_image_and_the_trend_and_removes_the_jitter():
    """A body walking away from the camera (depth 5 -> 8 m over 3 s) whose fit jitters along the rays: steadied,
    the root projects where it did, the body relative to it is unchanged, the root depth follows the walk within
    15 cm (the fit's depth is 13 cm off rms; the median of 31 frames), and the frame-to-frame jitter is gone."""
    from m3c.perception.contacts import steady_depth

    rng = np.random.default_rng(4)
    n = 90
    times = np.arange(n) / 30.0
    body = rng.normal(scale=0.3, size=(24, 3))
    body[0] = 0.0
    true = body[None] + np.stack([np.full(n, 0.2), np.full(n, 1.0), 5.0 + times], axis=1)[:, None]
    fitted = true * (1.0 + 0.02 * rng.normal(size=(n, 1, 1)))
    steady = steady_depth(fitted, times, 0.5)
    np.testing.assert_allclose(steady[:, 0, :2] / steady[:, 0, 2:], fitted[:, 0, :2] / fitted[:, 0, 2:], atol=1e-12)
    np.testing.assert_allclose(steady - steady[:, :1], fitted - fitted[:, :1], atol=1e-12)
    assert np.abs(steady[:, 0, 2] - true[:, 0, 2])[15:-15].max() < 0.15
    assert np.std(np.diff(steady[:, 0, 2])) < 0.25 * np.std(np.diff(fitted[:, 0, 2]))
    behind = fitted.copy()
    behind[3, :, 2] *= -1  # a frame behind the camera is left alone and does not enter the others' medians
    out = steady_depth(behind, times, 0.5)
    np.testing.assert_array_equal(out[3], behind[3])
    np.testing.assert_allclose(out[40], steady[40])


def test_steadied_depth_helps_the_contacts_of_a_jittering_fit(model, scene):
    """The walkers 8 m from a still camera with 4% of depth jitter along the rays (three noise draws): the
    contacts of the steadied fit agree better with the true ones than those of the raw fit."""
    from m3c.perception.contacts import steady_depth

    up = np.array([0.0, 1.0, 0.0])
    estimator = create("contacts", "kinematic")
    raw, steadied = [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        for truth in scene.truth:
            joints = track_joints(model, truth)
            seen = joints + np.array([0.0, -1.5, 8.0]) - joints[:, :1].mean(axis=0)
            jittered = seen * (1.0 + 0.04 * rng.normal(size=(len(seen), 1, 1)))
            true_feet = per_foot(truth.contacts)
            times = np.arange(len(seen)) / scene.fps
            raw.append((per_foot(estimator.estimate(jittered, scene.fps, up, False)) == true_feet).mean())
            steadied.append((per_foot(estimator.estimate(steady_depth(jittered, times, 1.0), scene.fps, up, False))
                             == true_feet).mean())
    assert np.mean(steadied) >= 0.85 and np.mean(steadied) > np.mean(raw) + 0.025, (raw, steadied)


def test_time_windows_hold_exactly_the_frames_within_reach():
    """Each frame's slice holds every frame within +- half_window (and the callers' test keeps exactly those): on
    times with gaps, frames whose distance is exactly the half window (sums of 1/30 s, as frame ids over fps make)
    and tracks of 0-3 frames. local_velocities' slope is then the least-squares line through those frames."""
    from m3c.perception.contacts import time_windows

    rng = np.random.default_rng(4)
    for n in (0, 1, 2, 3, 400):
        times = np.cumsum(rng.choice([1, 1, 1, 2, 3, 40], n)) / 30.0
        for half in (0.0, 0.1, 2 / 30, 1.0):
            lo, hi = time_windows(times, half)
            for t in range(n):
                within = np.flatnonzero(np.abs(times - times[t]) <= half)
                assert lo[t] <= within.min() and within.max() < hi[t]
                inside = lo[t] + np.flatnonzero(np.abs(times[lo[t]:hi[t]] - times[t]) <= half)
                np.testing.assert_array_equal(inside, within)
    times = np.cumsum(rng.choice([1, 2, 5], 60)) / 30.0
    points = rng.normal(size=(60, 2, 3))
    velocities = local_velocities(points, times, 0.1)
    for t in (0, 17, 59):
        near = np.flatnonzero(np.abs(times - times[t]) <= 0.1)
        if len(near) < 2:
            near = np.arange(max(t - 1, 0), min(t + 2, 60))
        slope = np.polyfit(times[near], points[near].reshape(len(near), -1), 1)[0].reshape(2, 3)
        np.testing.assert_allclose(velocities[t], slope, atol=1e-9)
