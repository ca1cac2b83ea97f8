"""Plane fits, per-frame association and per-track filling, against known synthetic ground truth and numpy."""

import numpy as np
import pytest

from m3c.ground import (CAMERA_UP, ContactTrack, GroundParams, estimate_ground_planes, fit_plane,
                        contact_vertices, foot_vertex_ids, frame_planes)


def angle_deg(a, b):
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))


def noisy_plane(rng, normal, offset, n, size=1.2, noise=0.005, outliers=0):
    """n points on {normal . x + offset = 0} around the plane point nearest (0.3, 1.2, 2.5), Gaussian noise
    along the normal, then outliers 5..40 cm above it (false contacts on shins and hands sit on one side)."""
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    q = np.array([0.3, 1.2, 2.5])
    centre = q - (normal @ q + offset) * normal
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a, b = rng.uniform(-size / 2, size / 2, size=(2, n + outliers))
    h = np.concatenate([rng.normal(scale=noise, size=n), rng.uniform(0.05, 0.40, size=outliers)])
    return centre + a[:, None] * u + b[:, None] * v + h[:, None] * normal, centre


def standing(rng, x, z, floor_y, feet=True, hands=False):
    """Contacts of a person at (x, z) on the horizontal plane y = floor_y (camera frame, y down): two
    25 x 10 cm soles of 40 points with 3 mm noise; optionally 15 hand points 0.8 m above them."""
    points, is_foot = [], []
    if feet:
        for side in (-0.1, 0.1):
            sole = np.stack([x + side + rng.uniform(-0.05, 0.05, 40),
                             floor_y + rng.normal(scale=0.003, size=40),
                             z + rng.uniform(-0.125, 0.125, 40)], axis=1)
            points.append(sole)
            is_foot.append(np.ones(40, bool))
    if hands:
        points.append(np.stack([x + 0.4 + rng.uniform(-0.05, 0.05, 15),
                                floor_y - 0.8 + rng.uniform(-0.05, 0.05, 15),
                                z + rng.uniform(-0.05, 0.05, 15)], axis=1))
        is_foot.append(np.zeros(15, bool))
    if not points:
        return np.empty((0, 3)), np.empty(0, bool)
    return np.concatenate(points), np.concatenate(is_foot)


def height_at(normal, offset, point):
    return float(np.dot(normal, point) + offset)


# --- fit_plane ---------------------------------------------------------------------------------------------


def test_total_least_squares_equals_numpy_svd():
    rng = np.random.default_rng(0)
    x, _ = noisy_plane(rng, [0.1, -1.0, 0.2], 1.4, 300, noise=0.02)
    fit = fit_plane(x, up=CAMERA_UP, robust=False)
    centroid = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - centroid)
    ref = vt[2] if vt[2] @ CAMERA_UP > 0 else -vt[2]
    np.testing.assert_allclose(fit.normal, ref, atol=1e-10)
    assert fit.offset == pytest.approx(-ref @ centroid, abs=1e-10)
    assert fit.rms == pytest.approx(s[2] / np.sqrt(len(x)), abs=1e-10)
    assert fit.inliers.all()


@pytest.mark.parametrize("seed", range(6))
def test_robust_fit_within_1cm_and_half_degree_with_outliers(seed):
    rng = np.random.default_rng(10 + seed)
    normal = np.array([rng.uniform(-0.3, 0.3), -1.0, rng.uniform(-0.3, 0.3)])
    normal /= np.linalg.norm(normal)
    offset = rng.uniform(1.0, 1.8)
    x, centre = noisy_plane(rng, normal, offset, 400, outliers=120)  # 23 % outliers
    fit = fit_plane(x, up=CAMERA_UP, seed=seed)
    assert angle_deg(fit.normal, normal) < 0.5
    assert abs(fit.offset - offset) < 0.01
    assert 380 <= fit.inliers.sum() <= 430
    assert not fit.inliers[400:].any() or fit.inliers[400:].mean() < 0.1
    # Plain least squares on the same points is off by centimetres: the robust option is doing the work.
    plain = fit_plane(x, up=CAMERA_UP, robust=False)
    assert abs(height_at(plain.normal, plain.offset, centre)) > 0.02


def test_normal_follows_the_given_up_and_signed_distance():
    rng = np.random.default_rng(1)
    x, _ = noisy_plane(rng, [0.0, 1.0, 0.0], -1.5, 200, noise=0.001)  # y = 1.5: floor 1.5 m below the camera
    camera = fit_plane(x, up=CAMERA_UP)
    assert camera.normal[1] < -0.999 and camera.offset == pytest.approx(1.5, abs=0.002)
    assert camera.signed_distance([0.0, 0.0, 0.0]) == pytest.approx(1.5, abs=0.01)  # camera height
    flipped = fit_plane(x, up=[0.0, 3.0, 0.0])
    np.testing.assert_allclose(flipped.normal, -camera.normal)
    assert flipped.offset == pytest.approx(-camera.offset)


def test_support_rule_and_degenerate_points_raise():
    rng = np.random.default_rng(2)
    x, _ = noisy_plane(rng, CAMERA_UP, 1.0, 49, noise=0.001)
    with pytest.raises(ValueError, match="49 points, fewer than min_support = 50"):
        fit_plane(x, up=CAMERA_UP, min_support=50)
    x, _ = noisy_plane(rng, CAMERA_UP, 1.0, 30, noise=0.001, outliers=40)
    with pytest.raises(ValueError, match="of 70 points lie within inlier_threshold"):
        fit_plane(x, up=CAMERA_UP, min_support=50)
    line = np.outer(np.linspace(0, 1, 30), [1.0, 0.0, 0.5]) + [0.0, 1.0, 2.0]
    with pytest.raises(ValueError, match="collinear"):
        fit_plane(line, up=CAMERA_UP, robust=False, min_support=3)


@pytest.mark.parametrize("kwargs,message", [
    (dict(points=np.zeros((30, 2)), up=CAMERA_UP), r"points must have shape \(N, 3\), got \(30, 2\)"),
    (dict(points=np.full((30, 3), np.nan), up=CAMERA_UP), r"points\[0\].*not finite"),
    (dict(points=np.zeros((30, 3)), up=[0.0, 0.0, 0.0]), "up must be a finite, non-zero 3-vector"),
    (dict(points=np.zeros((30, 3)), up=[0.0, 1.0]), r"up must have shape \(3,\)"),
    (dict(points=np.zeros((30, 3)), up=CAMERA_UP, inlier_threshold=0.0),
     "inlier_threshold must be a positive"),
    (dict(points=np.zeros((30, 3)), up=CAMERA_UP, min_support=2), "min_support must be >= 3"),
])
def test_fit_plane_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        fit_plane(**kwargs)


# --- one frame ---------------------------------------------------------------------------------------------


def two_level_frame(rng):
    """Person 0 on the floor 1.5 m below the camera, person 1 on a 20 cm step beside it, person 2 on the floor
    further back with its hands on a table (15 points: too few for a plane)."""
    people = [standing(rng, -0.5, 3.0, 1.5), standing(rng, 1.0, 3.0, 1.3),
              standing(rng, -0.6, 6.0, 1.5, hands=True)]
    points = np.concatenate([p for p, _ in people])
    person = np.concatenate([np.full(len(p), i) for i, (p, _) in enumerate(people)])
    is_foot = np.concatenate([f for _, f in people])
    return points, person, is_foot


def test_two_level_scene_gives_two_planes_and_the_right_association():
    points, person, is_foot = two_level_frame(np.random.default_rng(3))
    out = frame_planes(points, person, is_foot, up=CAMERA_UP)
    assert len(out.plane_ok) == 4 and out.plane_ok.sum() == 3  # the hands' cluster fails min_support
    assert out.via_feet.all() and (out.person_plane >= 0).all()
    assert len(set(out.person_plane.tolist())) == 3
    floor, step, back = [(out.normals[k], out.offsets[k]) for k in out.person_plane]
    # Each plane passes through its person's feet; the two levels are 20 cm apart.
    assert abs(height_at(*floor, [-0.5, 1.5, 3.0])) < 0.005
    assert abs(height_at(*step, [1.0, 1.3, 3.0])) < 0.005
    assert abs(height_at(*back, [-0.6, 1.5, 6.0])) < 0.005
    assert height_at(*floor, [1.0, 1.3, 3.0]) == pytest.approx(0.2, abs=0.03)
    for normal, _ in (floor, step, back):
        assert angle_deg(normal, CAMERA_UP) < 3.0
    # The DBSCAN labels are scikit-learn's.
    from sklearn.cluster import DBSCAN
    np.testing.assert_array_equal(out.labels, DBSCAN(eps=0.15, min_samples=10).fit(points).labels_)


def test_feet_first_then_other_contacts():
    rng = np.random.default_rng(4)
    stand_p, stand_f = standing(rng, 0.0, 3.0, 1.5)
    sit_p, _ = standing(rng, 0.3, 3.0, 1.5)  # touches the same floor, but not with its feet
    float_p, float_f = standing(rng, 3.0, 3.0, 1.1, feet=False, hands=True)  # 40 cm above any plane
    points = np.concatenate([stand_p, sit_p, float_p])
    person = np.repeat([0, 1, 2], [len(stand_p), len(sit_p), len(float_p)])
    is_foot = np.concatenate([stand_f, np.zeros(len(sit_p), bool), float_f])
    out = frame_planes(points, person, is_foot, up=CAMERA_UP)
    assert out.person_plane[0] >= 0 and out.via_feet[0]
    assert out.person_plane[1] == out.person_plane[0] and not out.via_feet[1]
    assert out.person_plane[2] == -1 and not out.via_feet[2]


def test_frame_planes_bad_input():
    points, person, is_foot = two_level_frame(np.random.default_rng(5))
    with pytest.raises(ValueError, match=r"person must have shape \(N=\d+,\)"):
        frame_planes(points, person[:-1], is_foot, up=CAMERA_UP)
    with pytest.raises(ValueError, match="person must be an integer or boolean array"):
        frame_planes(points, person.astype(float), is_foot, up=CAMERA_UP)
    with pytest.raises(ValueError, match="eps must be a positive"):
        frame_planes(points, person, is_foot, up=CAMERA_UP, params=GroundParams(eps=0.0))
    with pytest.raises(ValueError, match=r"person\[0\] = 0 is outside \[0, num_people = 0\)"):
        frame_planes(points, person, is_foot, up=CAMERA_UP, num_people=0)
    empty = frame_planes(np.empty((0, 3)), [], [], up=CAMERA_UP)
    assert empty.labels.shape == (0,) and empty.person_plane.shape == (0,)


# --- tracks ------------------------------------------------------------------------------------------------


def jump_scene(rng):
    """Track 0 walks on the floor (steps 0-3), jumps (4-6; at 6 only its hands touch a railing) and lands on a
    20 cm step (7-9); track 1 stands on the floor beside it throughout; track 2 starts later and never has
    foot contact."""
    def walker(s):
        if s < 4:
            return standing(rng, 0.1 * s, 3.0, 1.5)
        if s > 6:
            return standing(rng, 0.1 * s, 3.0, 1.3)
        return standing(rng, 0.6, 3.0, 0.9, feet=False, hands=s == 6)

    frames = np.arange(100, 110)
    t0 = [walker(s) for s in range(10)]
    t1 = [standing(rng, -2.0, 4.0, 1.5) for _ in range(10)]
    t2 = [standing(rng, 3.0, 5.0, 1.5, feet=False, hands=True) for _ in range(5)]
    return [ContactTrack(frames, [p for p, _ in t0], [f for _, f in t0]),
            ContactTrack(frames, [p for p, _ in t1], [f for _, f in t1]),
            ContactTrack(frames[5:], [p for p, _ in t2], [f for _, f in t2])]


def test_jump_keeps_the_last_plane():
    tracks = jump_scene(np.random.default_rng(6))
    out = estimate_ground_planes(tracks, up=CAMERA_UP)
    assert len(out) == 3
    walker, stander, never = out
    steps = np.arange(10)
    np.testing.assert_array_equal(walker.observed, (steps < 4) | (steps > 6))
    assert walker.valid.all() and stander.observed.all() and stander.valid.all()
    for s in range(4):
        assert abs(height_at(walker.normal[s], walker.offset[s], [0.1 * s, 1.5, 3.0])) < 0.005
    for s in (4, 5, 6):  # mid-air and hands-only frames keep exactly the plane of frame 3
        np.testing.assert_array_equal(walker.normal[s], walker.normal[3])
        assert walker.offset[s] == walker.offset[3]
    for s in range(7, 10):
        assert abs(height_at(walker.normal[s], walker.offset[s], [0.1 * s, 1.3, 3.0])) < 0.005
    for s in range(10):
        assert abs(height_at(stander.normal[s], stander.offset[s], [-2.0, 1.5, 4.0])) < 0.005
    np.testing.assert_array_equal(walker.frame_ids, np.arange(100, 110))
    assert not never.valid.any() and not never.observed.any() and np.isnan(never.normal).all()
    assert never.normal.shape == (5, 3) and never.offset.shape == (5,)


def test_linear_fill_interpolates_between_observations():
    tracks = jump_scene(np.random.default_rng(6))
    hold = estimate_ground_planes(tracks, up=CAMERA_UP)[0]
    linear = estimate_ground_planes(tracks, up=CAMERA_UP, params=GroundParams(fill="linear"))[0]
    np.testing.assert_array_equal(linear.observed, hold.observed)
    for s, w in [(4, 0.25), (5, 0.5), (6, 0.75)]:  # between frame 3 and frame 7
        blend = (1 - w) * hold.normal[3] + w * hold.normal[7]
        np.testing.assert_allclose(linear.normal[s], blend / np.linalg.norm(blend), atol=1e-12)
        assert linear.offset[s] == pytest.approx((1 - w) * hold.offset[3] + w * hold.offset[7], abs=1e-12)
    with pytest.raises(ValueError, match="fill must be one of"):
        estimate_ground_planes(tracks, up=CAMERA_UP, params=GroundParams(fill="cubic"))


def test_contact_track_from_vertices(synthetic_model_data):
    rng = np.random.default_rng(7)
    T, V = 4, synthetic_model_data.v_template.shape[0]
    vertices = rng.normal(size=(T, V, 3))
    prob = rng.uniform(size=(T, V))
    prob[0, :3] = 0.5  # exactly 0.5 is not in contact
    feet = foot_vertex_ids(synthetic_model_data.weights)
    assert len(feet) > 0
    ankles_and_feet = synthetic_model_data.weights[:, [7, 8, 10, 11]].sum(axis=1)
    np.testing.assert_array_equal(feet, np.flatnonzero(ankles_and_feet >= 0.5))
    track = ContactTrack.from_vertices(np.arange(T), vertices, prob, feet)
    for t in range(T):
        keep = prob[t] > 0.5
        np.testing.assert_array_equal(track.points[t], vertices[t][keep])
        np.testing.assert_array_equal(track.is_foot[t], np.isin(np.flatnonzero(keep), feet))


def test_track_bad_input():
    pts = [np.zeros((2, 3)), np.zeros((1, 3))]
    feet = [np.ones(2, bool), np.ones(1, bool)]
    with pytest.raises(ValueError, match=r"one entry per frame id \(T=3\)"):
        ContactTrack(np.arange(3), pts, feet)
    with pytest.raises(ValueError, match=r"points\[1\] must have shape \(M, 3\)"):
        ContactTrack(np.arange(2), [np.zeros((2, 3)), np.zeros((1, 2))], feet)
    with pytest.raises(ValueError, match=r"points\[0\] \(frame 0\) holds NaN"):
        ContactTrack(np.arange(2), [np.full((2, 3), np.nan), np.zeros((1, 3))], feet)
    with pytest.raises(ValueError, match=r"is_foot\[1\] must be a bool array of shape \(1,\)"):
        ContactTrack(np.arange(2), pts, [np.ones(2, bool), np.ones(3, bool)])
    with pytest.raises(ValueError, match="frame_ids must be a"):
        ContactTrack(np.array([0.0, 1.0]), pts, feet)
    with pytest.raises(ValueError, match="frame ids must be strictly increasing"):
        estimate_ground_planes([ContactTrack(np.array([3, 3]), pts, feet)], up=CAMERA_UP)
    with pytest.raises(ValueError, match="must be a ContactTrack"):
        estimate_ground_planes([pts], up=CAMERA_UP)
    with pytest.raises(ValueError, match="max_distance must be a positive"):
        estimate_ground_planes([ContactTrack(np.arange(2), pts, feet)], up=CAMERA_UP,
                               params=GroundParams(max_distance=-1.0))
    assert estimate_ground_planes([], up=CAMERA_UP) == []


def _ground_scene(rng, *, height, pitch_deg, depths, lateral, frames=150, depth_error=0.1, moving=False):
    """Contact points (one per frame) seen by a camera `height` metres above the ground y = 0 of a y-up world,
    pitched down by pitch_deg, at depths drawn from `depths` and lateral offsets from `lateral`; each point
    moved along its camera ray by a relative depth error that changes every 10 frames (it swings slowly).
    Returns (points, centers, camera x axis) in a frame where the first camera is at the origin, OpenCV axes."""
    pitch = np.radians(pitch_deg)
    # The camera's axes in the world (columns): x right, y down the image, z forward along -z, pitched down.
    R = np.stack([[1.0, 0, 0], [0, -np.cos(pitch), np.sin(pitch)], [0, -np.sin(pitch), -np.cos(pitch)]], axis=1)
    centers_w = np.tile([0.0, height, 0.0], (frames, 1))
    if moving:
        centers_w[:, 0] += np.linspace(0, 3, frames)
    forward = np.array([R[0, 2], 0.0, R[2, 2]]) / np.hypot(R[0, 2], R[2, 2])
    ground = centers_w * [1, 0, 1] + rng.uniform(*depths, frames)[:, None] * forward \
        + rng.uniform(*lateral, frames)[:, None] * [1.0, 0, 0]
    error = np.repeat(rng.normal(0, depth_error, frames // 10 + 1), 10)[:frames]
    seen = centers_w + (ground - centers_w) * (1 + error)[:, None]  # along the ray
    to_cam = lambda x: (x - centers_w[0]) @ R  # world -> first camera's frame (rows: x . R)
    return to_cam(seen), to_cam(centers_w), R.T @ np.array([0.0, 1.0, 0.0])


@pytest.mark.parametrize("moving", [False, True])
def test_ground_along_rays_recovers_a_pitched_cameras_height(moving):
    """People spread over depth and width: the fit recovers the camera's height and the ground's tilt from
    points scattered 10% along their rays, whatever the prior says about the pitch."""
    from m3c.ground import fit_ground_along_rays

    rng = np.random.default_rng(5)
    points, centers, true_up = _ground_scene(rng, height=1.8, pitch_deg=9.0, depths=(4, 12), lateral=(-3, 3),
                                             moving=moving)
    level = np.array([0.0, -1.0, 0.0])  # a level camera: 9 degrees off the truth in pitch
    fit = fit_ground_along_rays(points, centers, level, [1.0, 0.0, 0.0])
    assert np.degrees(np.arccos(fit.normal @ true_up)) < 1.5
    assert abs(fit.signed_distance(centers[0]) - 1.8) < 0.1
    assert fit.inliers.mean() > 0.9


def test_ground_along_rays_does_not_put_the_camera_on_the_floor():
    """People at one distance (one image row): perpendicular distances fit the plane of their rays, through
    the camera (camera height near 0); the ray fit finds the camera's height."""
    from m3c.ground import fit_ground_along_rays, fit_plane

    rng = np.random.default_rng(6)
    points, centers, true_up = _ground_scene(rng, height=2.0, pitch_deg=5.0, depths=(9.5, 11.5), lateral=(-4, 2))
    tls = fit_plane(points, up=true_up, robust=False)
    assert abs(tls.signed_distance(centers[0])) < 0.5  # the camera's height: the degenerate answer
    fit = fit_ground_along_rays(points, centers, true_up, [1.0, 0.0, 0.0])
    assert abs(fit.signed_distance(centers[0]) - 2.0) < 0.2
    assert np.degrees(np.arccos(fit.normal @ true_up)) < 1.5
    # Priors 4 degrees off give way to the points: rolled (6 m sideways) and pitched (2 m of depth, 150 frames).
    c, s = np.cos(np.radians(4)), np.sin(np.radians(4))
    pitched = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ true_up
    assert np.degrees(np.arccos(fit_ground_along_rays(points, centers, pitched, [1.0, 0, 0]).normal @ true_up)) < 1.5
    rolled = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ true_up
    across = fit_ground_along_rays(points, centers, rolled, [1.0, 0.0, 0.0])
    assert np.degrees(np.arccos(across.normal @ true_up)) < 1.5


def test_ground_along_rays_follows_the_prior_where_the_points_fix_nothing():
    from m3c.ground import RayGroundParams, fit_ground_along_rays

    rng = np.random.default_rng(7)
    points, centers, true_up = _ground_scene(rng, height=1.5, pitch_deg=3.0, depths=(7.0, 7.01), lateral=(0.1, 0.11))
    prior = true_up + [0.02, 0.0, 0.05]
    prior /= np.linalg.norm(prior)
    fit = fit_ground_along_rays(points, centers, prior, [1.0, 0.0, 0.0])
    assert np.degrees(np.arccos(fit.normal @ prior)) < 0.5
    assert np.all(np.abs(fit.signed_distance(points)) < 0.5)
    with pytest.raises(ValueError, match="at least 3"):
        fit_ground_along_rays(points[:2], centers[:2], prior, [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="both be"):
        fit_ground_along_rays(points, centers[:5], prior, [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="finite"):
        fit_ground_along_rays(points * np.nan, centers, prior, [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="parallel"):
        fit_ground_along_rays(points, centers, prior, prior)
    assert RayGroundParams().depth_error == 0.1


def _camera_track(rng, n: int, first_frame: int = 0) -> dict:
    contacts = rng.uniform(size=(n, 4))
    visible = rng.uniform(size=n) > 0.2
    return {"first_frame": first_frame, "num_frames": n, "root_orient": rng.normal(scale=0.3, size=(n, 3)),
            "body_pose": rng.normal(scale=0.2, size=(n, 23, 3)), "betas": rng.normal(size=10),
            "transl": rng.normal(size=(n, 3)) + [0.0, 0.0, 5.0], "contacts": contacts, "visible": visible}


def test_contact_vertices_match_the_skinned_feet_and_stay_bounded(synthetic_body_model):
    """contact_vertices against a direct reference (every vertex skinned, the contact rule written out), and its
    bound: a small max_points keeps the same vertex subset in every frame and the total within the bound."""
    rng = np.random.default_rng(3)
    model = synthetic_body_model
    tracks = [_camera_track(rng, 30), _camera_track(rng, 20, first_frame=5), {"first_frame": 0, "num_frames": 3}]
    weights = np.asarray(model.data.weights)
    feet = foot_vertex_ids(weights)
    joint_of_vertex = np.argmax(weights[feet][:, [7, 8, 10, 11]], axis=1)
    full = contact_vertices(model, tracks, 0.5)
    assert [len(p) for p in full] == [30, 20, 3]
    total = 0
    for track, points in zip(tracks[:2], full):
        poses = np.concatenate([track["root_orient"][:, None], track["body_pose"]], axis=1)
        vertices = model.forward(poses, track["betas"], track["transl"]).vertices[:, feet]
        for i in range(track["num_frames"]):
            keep = (track["contacts"][i] > 0.5)[joint_of_vertex] & track["visible"][i]
            np.testing.assert_allclose(points[i], vertices[i][keep], atol=1e-12)
            total += int(keep.sum())
    assert all(len(p) == 0 for p in full[2])
    assert total > 100
    bound = total // 5
    bounded = contact_vertices(model, tracks, 0.5, max_points=bound)
    step = -(-total // bound)
    kept = sum(len(p) for points in bounded for p in points)
    assert 0 < kept <= bound
    for track, points, reference in zip(tracks[:2], bounded, full):
        poses = np.concatenate([track["root_orient"][:, None], track["body_pose"]], axis=1)
        vertices = model.forward(poses, track["betas"], track["transl"]).vertices[:, feet[::step]]
        for i in range(track["num_frames"]):
            keep = (track["contacts"][i] > 0.5)[joint_of_vertex[::step]] & track["visible"][i]
            np.testing.assert_allclose(points[i], vertices[i][keep], atol=1e-12)
    with pytest.raises(ValueError, match="max_points must be >= 1"):
        contact_vertices(model, tracks, 0.5, max_points=0)


def test_contact_vertices_take_the_ground_contacts_where_given(synthetic_body_model):
    """A track whose contacts read the images carries ground_contacts (feet on the ground by heights): those pick
    the ground's points, not the planted-feet contacts."""
    rng = np.random.default_rng(4)
    track = _camera_track(rng, 12)
    planted_only = dict(track, ground_contacts=np.zeros_like(track["contacts"]))
    assert sum(len(p) for p in contact_vertices(synthetic_body_model, [planted_only], 0.5)[0]) == 0
    swapped = dict(track, contacts=np.zeros_like(track["contacts"]), ground_contacts=track["contacts"])
    for a, b in zip(contact_vertices(synthetic_body_model, [swapped], 0.5)[0],
                    contact_vertices(synthetic_body_model, [track], 0.5)[0]):
        np.testing.assert_array_equal(a, b)
