"""M3C's camera scale estimator (m3c.vo.scale): each observation on synthetic scenes of known scale, their fusion, and
the ground observation on the patch VO's own map of a room."""

import numpy as np
import pytest

from m3c.vo import (fuse, map_ground_plane, relative_ate, run_vo, scale_from_camera_height, scale_from_depth,
                    scale_from_planted_feet, umeyama_sim3)
from m3c.vo.scale import (DEPTH_WEIGHT, FEET_MODEL_SIGMA, FLOOR_RADIUS, FLOOR_SUPPORT, PERSON_SIZE_SIGMA,
                          PLAUSIBLE_CAMERA_HEIGHT_M, ScaleEstimate, ScaleObservation, floor_support, scale_subjects)
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


def _contacts_in_cameras(poses_m, rng, per_frame=6, noise=0.01):
    """Per frame, soles on the ground 2.5-4 m ahead of the camera, in that camera's coordinates (metres)."""
    out = []
    for pose in poses_m:
        ahead = pose[:3, 3] + pose[:3, 2] * rng.uniform(2.5, 4.0, (per_frame, 1))
        world = np.column_stack([ahead[:, 0] + rng.uniform(-0.3, 0.3, per_frame), np.full(per_frame, GROUND_Y),
                                 ahead[:, 2]])
        cam = (world - pose[:3, 3]) @ pose[:3, :3]
        out.append(cam + noise * rng.standard_normal(cam.shape))
    return out


def _vo_up(seed=3):
    """UP expressed in the VO frame that _to_vo(seed) builds."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return (q * np.sign(np.linalg.det(q))) @ UP


def _tilted(up, degrees, seed=0):
    axis = np.cross(up, np.random.default_rng(seed).standard_normal(3))
    axis /= np.linalg.norm(axis)
    angle = np.radians(degrees)
    return up * np.cos(angle) + np.cross(axis, up) * np.sin(angle)


def test_map_ground_plane_among_clutter():
    rng = np.random.default_rng(0)
    poses_m = _metric_cameras()
    ground, clutter = _ground_points(rng, 300), _clutter(rng, 600)
    points_m = np.concatenate([ground, clutter]) + 0.01 * rng.standard_normal((900, 3))
    points_vo, poses_vo = _to_vo(points_m, poses_m, 2.7)
    # The people's upright direction is only roughly the ground's normal.
    normal, offset, inliers = map_ground_plane(points_vo, poses_vo, _tilted(_vo_up(), 12.0))
    assert np.degrees(np.arccos(min(1.0, normal @ _vo_up()))) < 1.0
    assert inliers[:300].mean() > 0.9 and inliers[300:].mean() < 0.1
    # The plane lies below every camera, at the cameras' height in VO units.
    np.testing.assert_allclose(poses_vo[:, :3, 3] @ normal + offset, (GROUND_Y - poses_m[:, 1, 3]) / 2.7, rtol=0.02)


def test_map_ground_plane_needs_a_plane_below_the_cameras():
    rng = np.random.default_rng(4)
    poses_m = _metric_cameras()
    ceiling = _ground_points(rng, 200) - [0.0, 2 * GROUND_Y, 0.0]
    points_vo, poses_vo = _to_vo(ceiling, poses_m, 1.0)
    assert map_ground_plane(points_vo, poses_vo, _vo_up()) is None
    walls = _clutter(rng, 400)[:200]  # the wall beside the path: vertical, not a ground
    points_vo, poses_vo = _to_vo(walls, poses_m, 1.0)
    assert map_ground_plane(points_vo, poses_vo, _vo_up()) is None


def test_scale_from_camera_height_recovers_the_scale():
    rng = np.random.default_rng(1)
    poses_m = _metric_cameras(60)
    true_scale = 0.4
    points_vo, poses_vo = _to_vo(np.concatenate([_ground_points(rng, 300), _clutter(rng, 300)]), poses_m, true_scale)
    plane = map_ground_plane(points_vo, poses_vo, _vo_up())
    contacts = _contacts_in_cameras(poses_m, rng)
    for t in range(0, 60, 2):
        contacts[t] = np.zeros((0, 3))  # frames without a planted foot are skipped
    obs = scale_from_camera_height([contacts], poses_vo, plane[:2])
    assert obs.value == pytest.approx(true_scale, rel=0.01), obs
    assert obs.frames == 30 and obs.person_size
    assert 0 < obs.sigma < 0.02  # 1 cm of sole noise at 1.5 m, over 30 frames
    few = scale_from_camera_height([contacts[:8] + [np.zeros((0, 3))] * 52], poses_vo, plane[:2])
    assert few.value is None and "no person with 10 frames" in few.reason
    with pytest.raises(ValueError, match="frames"):
        scale_from_camera_height([contacts[:10]], poses_vo, plane[:2])


def test_camera_height_outside_the_plausible_range_widens_the_ground():
    """The cameras are 1.5 m above the ground: plausible, the source's sigma is its sampling error. Soles that
    come out 2.4x too far below the camera (3.6 m: a plane that is not the floor) leave the value 2.4x off, and
    the source says so: its sigma then holds log(3.6 / 3.0)."""
    rng = np.random.default_rng(1)
    poses_m = _metric_cameras(60)
    points_vo, poses_vo = _to_vo(np.concatenate([_ground_points(rng, 300), _clutter(rng, 300)]), poses_m, 0.4)
    plane = map_ground_plane(points_vo, poses_vo, _vo_up())
    contacts = _contacts_in_cameras(poses_m, rng)
    heights = GROUND_Y - poses_m[:, 1, 3]
    good = scale_from_camera_height([contacts], poses_vo, plane[:2])
    assert good.detail["camera_height_m"] == pytest.approx(np.median(heights), rel=0.02)
    assert not good.detail["camera_height_suspect"] and good.sigma < 0.02
    high = scale_from_camera_height([[2.4 * c for c in contacts]], poses_vo, plane[:2])
    assert high.value == pytest.approx(2.4 * good.value, rel=1e-9) and high.detail["camera_height_suspect"]
    height = high.detail["camera_height_m"]
    assert height == pytest.approx(2.4 * good.detail["camera_height_m"], rel=1e-9) and height > 3.0
    assert high.sigma == pytest.approx(np.hypot(high.detail["sampling_sigma"],
                                                np.log(height / PLAUSIBLE_CAMERA_HEIGHT_M[1])), rel=1e-12)
    low = scale_from_camera_height([[0.15 * c for c in contacts]], poses_vo, plane[:2])
    assert low.detail["camera_height_suspect"] and low.sigma > np.log(0.3 / (0.15 * 1.56))


def test_camera_height_weighs_each_person_once():
    """Each person's estimate carries that person's size error however many frames it has: two people, one seen
    in contact in 50 frames and 10% too large (its soles 10% too far below the camera), one in 12 frames and
    true, give their estimates' geometric mean, with an uncertainty from their scatter."""
    rng = np.random.default_rng(5)
    poses_m = _metric_cameras(60)
    true_scale = 0.4
    points_vo, poses_vo = _to_vo(np.concatenate([_ground_points(rng, 300), _clutter(rng, 300)]), poses_m, true_scale)
    plane = map_ground_plane(points_vo, poses_vo, _vo_up())
    empty = np.zeros((0, 3))
    big = [1.1 * c if t < 50 else empty for t, c in enumerate(_contacts_in_cameras(poses_m, rng, noise=0.0))]
    true = [c if t >= 48 else empty for t, c in enumerate(_contacts_in_cameras(poses_m, rng, noise=0.0))]
    obs = scale_from_camera_height([big, true], poses_vo, plane[:2])
    assert obs.detail["people"] == 2 and obs.frames == 62
    big_value, true_value = obs.detail["per_person"]
    assert big_value == pytest.approx(1.1 * true_scale, rel=2e-3) and true_value == pytest.approx(true_scale, rel=2e-3)
    assert obs.value == pytest.approx(np.sqrt(big_value * true_value), rel=1e-12)
    assert obs.sigma == pytest.approx(np.std(np.log([big_value, true_value]), ddof=1) / np.sqrt(2), rel=1e-9)
    # A person with too few frames is left out; a pooled median would have followed the larger person.
    alone = scale_from_camera_height([big, true[:55] + [empty] * 5], poses_vo, plane[:2])
    assert alone.detail["people"] == 1 and alone.value == pytest.approx(big_value, rel=1e-12)


def test_ground_needs_map_points_where_the_people_stand():
    """The people stand 2.5-4 m ahead of the cameras. A map whose only floor points lie 25-40 m ahead (a plain
    floor near the people, texture far off) still gives a plane at the right height, but nothing where they stand:
    the ground source refuses it. floor_support against a count in the metric scene, where each footprint is the
    contacts' own mean on the floor (the far floor alone, without clutter, so that its plane is the floor)."""
    rng = np.random.default_rng(6)
    poses_m = _metric_cameras(60)
    contacts = _contacts_in_cameras(poses_m, rng, noise=0.0)
    near = _ground_points(rng, 300)
    far = np.column_stack([rng.uniform(-3, 3, 300), np.full(300, GROUND_Y), rng.uniform(25, 40, 300)])
    for points_m, expected_value in ((near, True), (far, False)):
        scene = np.concatenate([points_m, _clutter(rng, 100 if expected_value else 0)])
        points_vo, poses_vo = _to_vo(scene, poses_m, 0.4)
        normal, offset, inliers = map_ground_plane(points_vo, poses_vo, _vo_up())
        support = floor_support(points_vo[inliers], (normal, offset), [contacts], poses_vo)
        metric = scene[inliers]
        footprints = [poses_m[t, :3, :3] @ contacts[t].mean(axis=0) + poses_m[t, :3, 3] for t in range(0, 60, 5)]
        heights = GROUND_Y - poses_m[::5, 1, 3]
        expected = np.zeros(len(metric), bool)
        for footprint, height in zip(footprints, heights):
            expected |= np.linalg.norm(metric - footprint, axis=1) < FLOOR_RADIUS * height
        assert support == int(expected.sum())
        obs = scale_from_camera_height([contacts], poses_vo, (normal, offset), floor_points=points_vo[inliers])
        assert obs.detail["floor_support"] == support
        if expected_value:
            assert support >= FLOOR_SUPPORT and obs.value == pytest.approx(0.4, rel=0.01)
        else:
            assert support == 0 and obs.value is None and "where the people stand" in obs.reason
            # The plane itself is right: unchecked, it would have given the scale.
            assert scale_from_camera_height([contacts], poses_vo, (normal, offset)).value == pytest.approx(0.4, rel=0.01)


def test_scale_subjects_are_the_people_near_the_camera():
    """The nearest person seen long enough sets the reference; people beyond 1.6x its depth and a passer-by nearer
    than it but seen briefly are judged against it."""
    steady = np.full(100, 4.0)
    depths = [steady, np.full(80, 6.0), np.full(80, 7.0), np.full(10, 2.0), np.full(60, 20.0), np.zeros(0)]
    np.testing.assert_array_equal(scale_subjects(depths), [True, True, False, True, False, False])
    # Nobody seen long enough: the nearest of all is the reference.
    np.testing.assert_array_equal(scale_subjects([np.full(5, 3.0), np.full(5, 6.0)]), [True, False])
    assert scale_subjects([]).shape == (0,)


def _planted_feet_scene(true_scale, depth_error, rng, T=60):
    """A camera walking forward and sideways past two people's feet, each planted for 10 frames at a time;
    the camera-local feet carry 1 cm image-plane noise and `depth_error` (relative) along the camera's z."""
    vo = np.tile(np.eye(4), (T, 1, 1))
    vo[:, :3, 3] = np.column_stack([0.3 * np.sin(np.linspace(0, 3, T)), np.zeros(T), np.linspace(0, 2.0, T)])
    joints, planted, frames = [], [], []
    for person in range(2):
        spots = np.column_stack([rng.uniform(-1, 1, T // 10), np.full(T // 10, 1.6),
                                 true_scale * 2.0 + rng.uniform(2, 5, T // 10)])
        world = np.repeat(spots, 10, axis=0)[:, None].repeat(4, axis=1)  # (T, 4, 3), the 4 contact joints
        cam = world - true_scale * vo[:, None, :3, 3]
        cam[..., :2] += 0.01 * rng.standard_normal(cam[..., :2].shape)
        cam[..., 2] *= 1.0 + depth_error * rng.standard_normal((T, 1))
        joints.append(cam)
        mask = np.ones((T, 4), bool)
        mask[9::10] = False  # the step between two plants
        planted.append(mask)
        frames.append(np.arange(T))
    return joints, planted, frames, vo


def test_scale_from_planted_feet_recovers_the_scale():
    rng = np.random.default_rng(2)
    joints, planted, frames, vo = _planted_feet_scene(1.7, 0.0, rng)
    obs = scale_from_planted_feet(joints, planted, frames, vo)
    assert obs.value == pytest.approx(1.7, rel=0.01), obs
    assert obs.detail["bootstrap_sigma"] < 0.02 and obs.detail["runs"] == 2 * 4 * 6
    assert obs.sigma == pytest.approx(np.hypot(obs.detail["bootstrap_sigma"], FEET_MODEL_SIGMA), rel=1e-12)
    # A static camera measures nothing.
    static = scale_from_planted_feet(joints, planted, frames, np.tile(np.eye(4), (60, 1, 1)))
    assert static.value is None and "does not move" in static.reason
    assert scale_from_planted_feet(joints, [np.zeros_like(m) for m in planted], frames, vo).reason == \
        "no planted foot"


def test_planted_feet_trust_the_image_plane_over_depth():
    """The stated noise model: a monocular body's depth is noisier than its image-plane position. With 10% depth
    noise per frame, the depth-weighted fit is closer to the truth than an isotropic one, and its bootstrap
    uncertainty covers its error."""
    errors = {DEPTH_WEIGHT: [], 1.0: []}
    for seed in range(6):
        joints, planted, frames, vo = _planted_feet_scene(1.7, 0.10, np.random.default_rng(seed))
        for weight in errors:
            obs = scale_from_planted_feet(joints, planted, frames, vo, depth_weight=weight)
            errors[weight].append(abs(np.log(obs.value / 1.7)))
            if weight == DEPTH_WEIGHT:
                assert errors[weight][-1] < 3 * obs.detail["bootstrap_sigma"] + 0.01
    assert np.mean(errors[DEPTH_WEIGHT]) < 0.5 * np.mean(errors[1.0])


def test_fuse_weights_by_uncertainty_and_shares_the_person_size_error():
    feet = ScaleObservation("planted feet", 2.2, 0.2, 100)
    ground = ScaleObservation("ground", 2.0, 0.02, 100)
    est = fuse([feet, ground])
    w = np.array([1 / 0.2 ** 2, 1 / 0.02 ** 2])
    mean = (w * np.log([2.2, 2.0])).sum() / w.sum()
    assert est.value == pytest.approx(np.exp(mean), rel=1e-12)
    assert est.sigma == pytest.approx(np.hypot(1 / np.sqrt(w.sum()), PERSON_SIZE_SIGMA), rel=1e-12)
    assert est.source == "planted feet+ground" and est.consistent
    # A depth map is independent of the people's size: it is fused with their group's mean.
    depth = ScaleObservation("depth map", 1.98, 0.03, 50, person_size=False)
    est = fuse([feet, ground, depth])
    group = (mean, np.hypot(1 / np.sqrt(w.sum()), PERSON_SIZE_SIGMA))
    w2 = np.array([1 / group[1] ** 2, 1 / 0.03 ** 2])
    assert est.value == pytest.approx(np.exp((w2 * [group[0], np.log(1.98)]).sum() / w2.sum()), rel=1e-12)
    assert est.sigma == pytest.approx(1 / np.sqrt(w2.sum()), rel=1e-12)
    assert est.spread == 0.0 and est.confidence == "high" and est.disagreement() == ""
    # Disagreement beyond 3 combined standard deviations is flagged; the DerSimonian-Laird between-source variance
    # joins each source's (two sources: tau^2 = (Q - 1) / (w1 + w2 - (w1^2 + w2^2) / (w1 + w2))), and the 2-sigma
    # interval reaches both values; nothing usable gives the default.
    apart = fuse([ScaleObservation("planted feet", 5.0, 0.05), ground])
    logs, w = np.log([5.0, 2.0]), np.array([1 / 0.05 ** 2, 1 / 0.02 ** 2])
    q = (w * (logs - (w * logs).sum() / w.sum()) ** 2).sum()
    tau2 = (q - 1) / (w.sum() - (w ** 2).sum() / w.sum())
    w_re = 1 / (1 / w + tau2)
    mean = (w_re * logs).sum() / w_re.sum()
    assert not apart.consistent and apart.spread == pytest.approx(np.sqrt(tau2), rel=1e-12)
    assert apart.value == pytest.approx(np.exp(mean), rel=1e-12)
    assert apart.sigma == pytest.approx(max(np.hypot(1 / np.sqrt(w_re.sum()), PERSON_SIZE_SIGMA),
                                            np.abs(logs - mean).max() / 2), rel=1e-12)
    assert apart.confidence == "low" and "disagree beyond their uncertainty" in apart.disagreement()
    assert apart.to_dict()["confidence"] == "low" and apart.to_dict()["spread"] == apart.spread
    none = fuse([ScaleObservation("ground", reason="no map points")], default=1.0)
    assert none.value == 1.0 and none.sigma is None and none.source == "default" and none.confidence == "none"


def _covers(estimate, truth, k=2.0):
    return abs(np.log(estimate.value / truth)) <= k * estimate.sigma


@pytest.mark.parametrize("feet, ground", [((0.20, 0.46), (2.37, 0.026)),   # a crowd and a barely moving camera
                                          ((11.4, 0.23), (7.0, 0.009))])   # a plain hall floor: 2.1 sigma apart
def test_fuse_covers_either_source_when_they_disagree(feet, ground):
    """The issue's two real clips: feet and ground apart by more than their errors. Whichever of them is right,
    the fused 2-sigma interval covers it (the tighter source is not simply kept)."""
    est = fuse([ScaleObservation("planted feet", *feet), ScaleObservation("ground", *ground)])
    for truth in (feet[0], ground[0]):
        assert _covers(est, truth), (est.value, est.sigma, truth)
    fixed = np.exp(np.average(np.log([feet[0], ground[0]]), weights=[feet[1] ** -2, ground[1] ** -2]))
    assert abs(np.log(fixed / ground[0])) < 0.01 and not _covers(ScaleEstimate(fixed, 0.07, "fixed"), feet[0])
    assert est.spread > 0 and est.confidence in ("low", "medium")


def test_fuse_coverage_against_known_truth():
    """Synthetic sources against a known scale. Honest sources (their error drawn from their sigma): unchanged, the
    inverse-variance mean. One source biased while claiming 1-3% (a wrong map plane), by 3.5-8 times the other's
    sigma (sources in conflict: a bias within the other's noise no fusion can see): the truth stays inside the
    fused 2-sigma interval in at least 95% of the draws; the fixed-effects mean would miss it in most."""
    rng = np.random.default_rng(0)
    covered, fixed_covered, trials = 0, 0, 400
    for _ in range(trials):
        truth = np.exp(rng.uniform(-2, 3))
        feet_sigma, ground_sigma = rng.uniform(0.2, 0.5), rng.uniform(0.01, 0.03)
        feet = ScaleObservation("planted feet", truth * np.exp(feet_sigma * rng.standard_normal()), feet_sigma)
        bias = np.exp(rng.choice([-1, 1]) * rng.uniform(3.5, 8.0) * feet_sigma)
        ground = ScaleObservation("ground", truth * bias, ground_sigma)
        est = fuse([feet, ground])
        covered += _covers(est, truth)
        w = np.array([feet_sigma ** -2, ground_sigma ** -2])
        fixed_mean = np.exp((w * np.log([feet.value, ground.value])).sum() / w.sum())
        fixed_covered += abs(np.log(fixed_mean / truth)) <= 2 * np.hypot(1 / np.sqrt(w.sum()), PERSON_SIZE_SIGMA)
    assert covered / trials >= 0.95 and fixed_covered / trials < 0.2
    # Honest sources that agree within their errors: the estimate is the inverse-variance mean.
    for _ in range(50):
        truth = np.exp(rng.uniform(-2, 3))
        feet = ScaleObservation("planted feet", truth * np.exp(0.02 * rng.standard_normal()), 0.25)
        ground = ScaleObservation("ground", truth * np.exp(0.01 * rng.standard_normal()), 0.02)
        est = fuse([feet, ground])
        w = np.array([0.25 ** -2, 0.02 ** -2])
        assert est.value == pytest.approx(np.exp((w * np.log([feet.value, ground.value])).sum() / w.sum()),
                                          rel=1e-12)
        assert est.spread == 0 and est.consistent and _covers(est, truth)


def test_scale_from_depth_maps():
    rng = np.random.default_rng(5)
    poses_m = _metric_cameras(10)
    true_scale = 3.0
    points_m = _ground_points(rng, 400)
    points_vo, poses_vo = _to_vo(points_m, poses_m, true_scale)
    W, H, f = 320, 240, 250.0
    maps = np.zeros((10, H, W))
    for t, pose in enumerate(poses_m):  # the metric depth of every map point at its pixel
        cam = (points_m - pose[:3, 3]) @ pose[:3, :3]
        front = cam[:, 2] > 0.1
        u = np.round(f * cam[front, 0] / cam[front, 2] + W / 2).astype(int)
        v = np.round(f * cam[front, 1] / cam[front, 2] + H / 2).astype(int)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        maps[t, v[ok], u[ok]] = cam[front][ok, 2] * (1 + 0.02 * rng.standard_normal(ok.sum()))
    obs = scale_from_depth(points_vo, poses_vo, maps, [f, f, W / 2, H / 2])
    assert obs.value == pytest.approx(true_scale, rel=0.01) and not obs.person_size
    blank = scale_from_depth(points_vo, poses_vo, np.zeros((10, H, W)), [f, f, W / 2, H / 2])
    assert blank.value is None and "known depth" in blank.reason


def test_scale_of_the_patch_vo_map_of_a_room():
    """End to end: the VO's own map of the textured room; the floor (y = ROOM_MAX[1], world y down) is the
    ground, the walls and the far end are clutter. Truth: the similarity that aligns the VO trajectory."""
    seq = render_sequence(forward_trajectory(60), seed=0)
    result = run_vo(seq.frames, intrinsics=seq.intrinsics)
    assert relative_ate(result.world_from_cam, seq.world_from_cam) <= 0.01
    true_scale, rotation, _ = umeyama_sim3(result.camera_centres, seq.camera_centres)
    plane = map_ground_plane(result.points, result.world_from_cam, rotation.T @ UP)
    assert plane is not None
    rng = np.random.default_rng(0)
    contacts = []
    for pose in seq.world_from_cam:  # soles on the floor 1.5-3 m ahead, in each camera
        ahead = pose[:3, 3] + pose[:3, 2] * rng.uniform(1.5, 3.0, (4, 1))
        ahead[:, 1] = ROOM_MAX[1]
        contacts.append((ahead - pose[:3, 3]) @ pose[:3, :3])
    obs = scale_from_camera_height([contacts], result.world_from_cam, plane[:2])
    assert obs.value == pytest.approx(true_scale, rel=0.02), obs


def test_a_turning_camera_is_told_from_a_moving_one():
    from m3c.vo.scale import translation_baseline, turns_in_place

    rng = np.random.default_rng(6)
    points = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-1, 2, 300), rng.uniform(8, 12, 300)])
    depth = np.median(np.linalg.norm(points, axis=1))  # from the middle camera, near the origin in both paths
    turning = np.tile(np.eye(4), (30, 1, 1))
    turning[:, :3, 3] = 0.05 * rng.standard_normal((30, 3))  # odometry noise around one spot
    slow = np.tile(np.eye(4), (30, 1, 1))
    slow[:, 2, 3] = np.linspace(-0.25, 0.25, 30)  # 0.5 units straight ahead: short, but it goes somewhere
    extent, wander = translation_baseline(slow, points)
    assert extent == pytest.approx(0.5 / depth, rel=0.01) and wander == pytest.approx(1.0)
    assert extent < 0.1  # as small as the turning camera's noise ...
    assert turns_in_place(turning, points) and not turns_in_place(slow, points)  # ... but not wandering
    assert not turns_in_place(turning, points, min_baseline=0.0)  # the setting that keeps every translation
    assert translation_baseline(slow, np.zeros((0, 3))) is None
    assert translation_baseline(np.tile(np.eye(4), (5, 1, 1)), points) is None


def test_info_warns_when_the_world_size_is_uncertain():
    from m3c.io.results import _world_size_warning

    apart = fuse([ScaleObservation("planted feet", 0.20, 0.46), ScaleObservation("ground", 2.37, 0.026)])
    line = _world_size_warning({"scale_estimate": apart.to_dict()})[0]
    assert "world's size is uncertain" in line and "planted feet 0.2 (+-46%)" in line
    assert f"factor of {np.exp(2 * apart.sigma):.2f}" in line
    agree = fuse([ScaleObservation("planted feet", 2.2, 0.2), ScaleObservation("ground", 2.0, 0.02)])
    assert _world_size_warning({"scale_estimate": agree.to_dict()}) == [] and _world_size_warning({}) == []
    wide = fuse([ScaleObservation("planted feet", 2.2, 0.4)])
    assert wide.confidence == "low" and "factor of" in _world_size_warning({"scale_estimate": wide.to_dict()})[0]


def _followed_walker(scale, stride=0.9 / 30, leg=0.8, step_legs=None, n=150, camera_share=1.0, seed=0):
    """A pelvis walking straight along +z at the step GAIT_STEP_LEGS * leg per half stride (metres a frame), with
    a gait's sway, seen from a camera that follows it (camera_share of its travel, the rest the person's own in
    the camera) 4 m behind; VO poses in units of `scale` metres."""
    from m3c.vo.scale import GAIT_STEP_LEGS

    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.float64)
    speed = 2.0 * stride * (step_legs or GAIT_STEP_LEGS) * leg  # metres a frame
    pelvis = np.column_stack([0.03 * np.sin(2 * np.pi * stride * t), np.full(n, -0.9), speed * t])
    centres = np.column_stack([np.zeros(n), np.zeros(n), camera_share * speed * t - 4.0])
    R = np.stack([look_rotation(0.05 * np.sin(0.1 * i), -0.1, 0.0) for i in range(n)])
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = R
    poses[:, :3, 3] = centres / scale
    in_camera = np.einsum("nji,nj->ni", R, pelvis - centres) + rng.normal(0, 0.01, (n, 3))
    return in_camera, poses, t


@pytest.mark.parametrize("scale", [0.3, 7.0, 72.0])
def test_scale_from_gait_recovers_the_scale_of_a_followed_walker(scale):
    from m3c.vo.scale import GAIT_MODEL_SIGMA, GAIT_STEP_SIGMA, scale_from_gait

    pelvis, poses, t = _followed_walker(scale)
    obs = scale_from_gait([pelvis], [0.9 / 30], [0.8], [t.astype(int)], poses, UP)
    assert obs.value == pytest.approx(scale, rel=0.01)
    # The travel is the camera's: sensitivity 1, the step's spread and the gait's model error.
    assert obs.sigma == pytest.approx(np.hypot(GAIT_STEP_SIGMA, GAIT_MODEL_SIGMA), rel=0.01)
    # Half the walk the person's own in the camera: the scale still follows, less tightly.
    pelvis, poses, t = _followed_walker(scale, camera_share=0.6)
    half = scale_from_gait([pelvis], [0.9 / 30], [0.8], [t.astype(int)], poses, UP)
    assert half.value == pytest.approx(scale, rel=0.02) and half.sigma > obs.sigma
    # A step 30% longer than a walk's (a jog) taken for a walk reads as a 1.3x smaller scale, inside 2 sigma.
    pelvis, poses, t = _followed_walker(scale, step_legs=1.3 * 0.87)
    jog = scale_from_gait([pelvis], [0.9 / 30], [0.8], [t.astype(int)], poses, UP)
    assert jog.value == pytest.approx(scale / 1.3, rel=0.02) and abs(np.log(jog.value / scale)) < 2 * jog.sigma


def test_scale_from_gait_needs_a_gait_and_a_camera_that_carries_the_travel():
    from m3c.vo.scale import scale_from_gait

    pelvis, poses, t = _followed_walker(5.0)
    assert scale_from_gait([pelvis], [None], [0.8], [t.astype(int)], poses, UP).reason == "no steady gait"
    # A still camera: the person's travel is all his own in the camera; no scale in it.
    pelvis, poses, t = _followed_walker(5.0, camera_share=0.0)
    obs = scale_from_gait([pelvis], [0.9 / 30], [0.8], [t.astype(int)], poses, UP)
    assert not obs.usable() and "camera" in obs.reason


def test_fuse_adds_a_spread_only_where_cochrans_test_finds_one():
    """A wide source 2.3 of its sigmas from a tight one (the hard suite's plain-floor handheld camera: planted feet
    +12% +-23%, ground +2% +-5%, gait +221% +-51%) is within its error: the fusion is the inverse-variance mean,
    not a random-effects mean pulled towards the wide source. Honest sources drawn from their sigmas get no spread
    in about 95% of draws (the test's level); sources far apart get one."""
    from m3c.vo.scale import HETEROGENEITY_ALPHA, between_source_variance

    feet, ground = ScaleObservation("planted feet", 1.12, 0.23), ScaleObservation("ground", 1.02, 0.05)
    gait = ScaleObservation("gait", 3.21, 0.51)
    est = fuse([feet, ground, gait])
    logs, sigmas = np.log([1.12, 1.02, 3.21]), np.array([0.23, 0.05, 0.51])
    assert between_source_variance(logs, sigmas) > 0.05  # DerSimonian-Laird alone: tau 0.26
    assert est.spread == 0.0 and est.consistent
    people = _weighted_mean(logs, sigmas)
    assert est.value == pytest.approx(np.exp(people[0]), rel=1e-12)
    assert est.sigma == pytest.approx(np.hypot(people[1], PERSON_SIZE_SIGMA), rel=1e-12)
    assert abs(np.log(est.value)) < 0.05  # within 5% of the tight source's truth (1.0)
    rng = np.random.default_rng(3)
    spread = 0
    for _ in range(2000):
        draws = rng.standard_normal(3) * sigmas
        spread += between_source_variance(draws, sigmas, HETEROGENEITY_ALPHA) > 0
    assert abs(spread / 2000 - HETEROGENEITY_ALPHA) < 0.015
    assert fuse([ScaleObservation("planted feet", 5.0, 0.05), ground]).spread > 0


def _weighted_mean(logs, sigmas):
    weights = 1.0 / np.square(sigmas)
    return float(np.sum(weights * logs) / weights.sum()), float(1.0 / np.sqrt(weights.sum()))


def test_fuse_sets_aside_the_one_source_that_disagrees_with_the_others():
    """The bundled clip: planted feet 24 (+-35%) against the ground 71 (+-1%), 3.1 combined sigmas apart; a third
    source that sides with one of them settles it. Two camps that each agree within themselves are left to the
    random-effects mean."""
    feet = ScaleObservation("planted feet", 10.0, 0.2)
    ground = ScaleObservation("ground", 71.3, 0.01)
    gait = ScaleObservation("gait", 75.0, 0.2)
    est = fuse([feet, ground, gait])
    assert est.consistent and est.source == "ground+gait"
    aside = next(o for o in est.observations if o.source == "planted feet")
    assert aside.value is None and aside.detail["set_aside"]["value"] == 10.0 and "disagrees with" in aside.reason
    assert est.value == pytest.approx(fuse([ground, gait]).value, rel=1e-12)
    assert feet.value == 10.0  # the caller's observation is left as it was
    # Without the third source nothing is set aside.
    assert fuse([feet, ground]).source == "planted feet+ground" and not fuse([feet, ground]).consistent
    # Two camps: no source disagrees with both others.
    camps = fuse([ScaleObservation("planted feet", 10.0, 0.05), ScaleObservation("ground", 11.0, 0.05),
                  ScaleObservation("gait", 40.0, 0.05), ScaleObservation("depth map", 44.0, 0.05, person_size=False)])
    assert not camps.consistent and all(o.usable() for o in camps.observations)
