"""Node building blocks against hand-checked cases and independent computations: mask records, the patches node,
crop-to-full cameras (CLIFF), gap filling (linear, SO(3) slerp), local tracks, SMPL frame changes, the
gravity-aligned world, the camera scale from planted feet. Box processing, isolation and patch sampling:
test_perception_boxes.py."""

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.nodes.records import decode_mask, encode_masks, mask_in_region
from m3c.motion.interpolate import interpolate_linear, interpolate_rotations
from m3c.nodes.local_tracks import LocalTracksNode
from m3c.perception.boxes import crop_to_full_camera, full_to_crop_camera, process_boxes
from m3c.ground.world_frame import gravity_frame
from m3c.motion.scale import estimate_camera_scale
from m3c.pipeline import InputError, PipelineError


def test_masks_round_trip_and_regions(rng):
    masks = [(rng.uniform(size=(7, 5)) > 0.5, 3, 4), (np.ones((2, 9), bool), 0, 0), (np.zeros((0, 0), bool), 1, 1)]
    encoded = encode_masks(masks)
    for n, (mask, x0, y0) in enumerate(masks):
        got, gx, gy = decode_mask(encoded, n)
        np.testing.assert_array_equal(got, mask)
        assert (gx, gy) == (x0, y0)
    # A region overlapping mask 0 partly: pixels (x, y) in [2, 6) x [6, 20).
    region = mask_in_region(encoded, 0, (2, 6, 6, 20))
    expected = np.zeros((14, 4), bool)
    expected[0:5, 1:4] = masks[0][0][2:7, 0:3]
    np.testing.assert_array_equal(region, expected)


@pytest.mark.parametrize("intrinsics", [(1000.0, 1000.0, 480.0, 270.0), (900.0, 1100.0, 500.0, 260.0)])
def test_crop_camera_to_full_image(rng, intrinsics):
    square = np.array([[300.0, 100.0, 500.0, 300.0], [20.0, 50.0, 120.0, 150.0]])
    crop_cam = np.array([[0.9, 0.05, 0.2], [1.1, -0.1, 0.0]])
    transl = crop_to_full_camera(crop_cam, square, intrinsics)
    # The body origin projects where the weak-perspective camera put it: box centre + b s (tx, ty) / 2.
    fx, fy, cx, cy = intrinsics
    side = square[:, 2] - square[:, 0]
    centre = (square[:, :2] + square[:, 2:]) / 2
    expected = centre + side[:, None] * crop_cam[:, :1] * crop_cam[:, 1:] / 2
    projected = np.stack([fx * transl[:, 0] / transl[:, 2] + cx, fy * transl[:, 1] / transl[:, 2] + cy], 1)
    np.testing.assert_allclose(projected, expected, rtol=1e-12)
    # Depth: a body of height h metres appears h * s * b / 2 pixels tall in both models (mean focal).
    np.testing.assert_allclose(transl[:, 2], (fx + fy) / (side * crop_cam[:, 0]))
    np.testing.assert_allclose(full_to_crop_camera(transl, square, intrinsics), crop_cam, atol=1e-12)
    # CLIFF's formula where fx = fy.
    if fx == fy:
        bs = side * crop_cam[:, 0]
        np.testing.assert_allclose(transl[:, 0], crop_cam[:, 1] + 2 * (centre[:, 0] - cx) / bs)


def test_slerp_follows_the_shorter_arc_at_constant_speed():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    times = np.array([0.0, 4.0])
    rotvecs = np.stack([0.2 * axis, 1.0 * axis])[:, None]  # (K, 1, 3)
    out = interpolate_rotations(times, rotvecs, np.arange(5.0))
    np.testing.assert_allclose(out[:, 0], np.outer([0.2, 0.4, 0.6, 0.8, 1.0], axis), atol=1e-12)
    # 3.0 rad and -3.0 rad about z are 0.28 rad apart across pi: the midpoint is pi, not 0.
    z = np.array([0.0, 0.0, 1.0])
    mid = interpolate_rotations(times, np.stack([3.0 * z, -3.0 * z])[:, None], np.array([2.0]))[0, 0]
    assert Rotation.from_rotvec(mid).magnitude() == pytest.approx(np.pi, abs=1e-9)
    # Beyond the ends: held.
    np.testing.assert_allclose(interpolate_rotations(times, rotvecs, np.array([-3.0, 9.0]))[:, 0],
                               [0.2 * axis, 1.0 * axis], atol=1e-12)


def test_interpolate_linear():
    out = interpolate_linear(np.array([1.0, 3.0]), np.array([[0.0, 10.0], [2.0, 30.0]]), np.arange(5.0))
    np.testing.assert_allclose(out, [[0, 10], [0, 10], [1, 20], [2, 30], [2, 30]])


class FakeContext:
    log = logging.getLogger("test")


def test_local_tracks_gather_fill_and_drop(rng):
    # Perception's tracks: 5 seen in frames 0, 1, 3 (detection rows 0, 1, 3), 9 only in frame 2 (row 2).
    frame = np.array([0, 1, 3])
    n = len(frame)
    keypoints = rng.uniform(10, 100, size=(n, 21, 3)).astype(np.float32)  # COCO-17 and the foot points
    keypoints[..., 2] = 0.8
    pose = rng.normal(scale=0.3, size=(n, 24, 3))
    betas = rng.normal(size=(n, 10))
    transl = np.array([[0.0, 0, 4], [1.0, 0, 4], [3.0, 0, 4]])
    square = np.tile([100.0, 100.0, 300.0, 300.0], (n, 1)).astype(np.float32)
    intrinsics = np.array([1000.0, 1000.0, 480.0, 270.0])
    five = {"track_id": 5, "frame": frame, "detection": np.array([0, 1, 3]), "square": square,
            "keypoints": keypoints, "pose": pose, "betas": betas,
            "crop_cam": full_to_crop_camera(transl, square, intrinsics),
            "contacts": rng.uniform(size=(n, 4)).astype(np.float32)}
    nine = {"track_id": 9, "frame": np.array([2]), "detection": np.array([2]), "square": square[:1],
            "keypoints": keypoints[:1], "pose": pose[:1], "betas": betas[:1], "transl": np.array([[0.0, 0, 5]])}
    inputs = {"video": {"num_frames": 4}, "camera": {"intrinsics": intrinsics}, "tracks": {"tracks": [nine, five]}}
    node = LocalTracksNode("local_tracks", LocalTracksNode.Config(min_visible_frames=2, gap_confidence=0.5))
    out = node.run(FakeContext(), inputs)["tracks"]
    assert [t["track_id"] for t in out["tracks"]] == [5]  # track 9 (one frame) dropped
    track = out["tracks"][0]
    assert track["first_frame"] == 0 and track["num_frames"] == 4
    np.testing.assert_array_equal(track["visible"], [True, True, False, True])
    np.testing.assert_array_equal(track["detection"], [0, 1, -1, 3])
    np.testing.assert_allclose(track["transl"], [[0, 0, 4], [1, 0, 4], [2, 0, 4], [3, 0, 4]], atol=1e-9)
    assert track["keypoints"].shape == (4, 17, 3)  # the optimizer's COCO-17
    gap = (keypoints[1, :17] + keypoints[2, :17]) / 2
    np.testing.assert_allclose(track["keypoints"][2, :, :2], gap[:, :2], rtol=1e-6)
    np.testing.assert_allclose(track["keypoints"][2, :, 2], 0.5 * gap[:, 2], rtol=1e-6)
    np.testing.assert_array_equal(track["keypoints"][1], keypoints[1, :17])
    np.testing.assert_allclose(track["contacts"][2], (five["contacts"][1] + five["contacts"][2]) / 2, rtol=1e-6)
    # Rotations in the gap: the geodesic midpoint of frames 1 and 3.
    for j in range(24):
        a, b = Rotation.from_rotvec(pose[1, j]), Rotation.from_rotvec(pose[2, j])
        mid = a * Rotation.from_rotvec((a.inv() * b).as_rotvec() / 2)
        got = Rotation.from_rotvec(track["root_orient"][2] if j == 0 else track["body_pose"][2, j - 1])
        assert (got.inv() * mid).magnitude() < 1e-9
    np.testing.assert_allclose(track["betas"], betas.mean(axis=0))
    with pytest.raises(InputError, match="no person was found.*id 5 in 3 frames, id 9 in 1 frame"):
        LocalTracksNode("local_tracks", LocalTracksNode.Config(min_visible_frames=10)).run(FakeContext(), inputs)
    # A track that lists a frame twice is refused, named.
    twice = dict(five, frame=np.array([0, 1, 1]))
    with pytest.raises(PipelineError, match="track 5: its frames must increase"):
        node.run(FakeContext(), dict(inputs, tracks={"tracks": [twice]}))


def test_transform_smpl_moves_the_mesh_rigidly(synthetic_body_model, rng):
    model = synthetic_body_model
    n = 3
    pose = rng.normal(scale=0.4, size=(n, model.num_joints, 3))
    betas = rng.normal(size=model.num_betas)
    transl = rng.normal(size=(n, 3))
    target_from_source = np.tile(np.eye(4), (n, 1, 1))
    target_from_source[:, :3, :3] = Rotation.random(n, random_state=1).as_matrix()
    target_from_source[:, :3, 3] = rng.normal(size=(n, 3))
    j0 = rest_root_joint(model, betas)
    assert np.linalg.norm(j0) > 1e-3  # the synthetic model's root is off the origin: the test means something
    root, new_transl = transform_smpl(target_from_source, pose[:, 0], transl, j0)
    moved = model.forward(np.concatenate([root[:, None], pose[:, 1:]], 1), betas, new_transl).vertices
    original = model.forward(pose, betas, transl).vertices
    expected = np.einsum("nij,nvj->nvi", target_from_source[:, :3, :3], original) + target_from_source[:, None, :3, 3]
    np.testing.assert_allclose(moved, expected, atol=1e-9)


def test_gravity_frame_puts_the_ground_at_y0_below_the_first_camera():
    up = np.array([0.1, -0.95, 0.2])
    up /= np.linalg.norm(up)
    camera = np.eye(4)
    camera[:3, :3] = Rotation.from_rotvec([0.3, 0.2, 0.1]).as_matrix()
    camera[:3, 3] = [1.0, -2.0, 0.5]
    world_from_vo = gravity_frame(up, camera, height=1.7)
    R = world_from_vo[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ up, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(world_from_vo[:3, :3] @ camera[:3, 3] + world_from_vo[:3, 3], [0, 1.7, 0],
                               atol=1e-12)
    forward = R @ camera[:3, 2]
    assert abs(forward[0]) < 1e-12 and forward[2] > 0  # the first camera looks along +z (tilted in y)


def camera_local_scene(vo_scale: float):
    """The synthetic scene's true people as camera-frame track dicts (as local_tracks gives them)."""
    from m3c.body import default_body_model
    from m3c.eval.scenes import make_scene

    model = default_body_model()
    scene = make_scene(model, num_people=2, num_frames=40, seed=3, vo_scale=vo_scale)
    cam_from_world = np.linalg.inv(scene.cameras_true.world_from_cam)
    tracks = []
    for k, truth in enumerate(scene.truth):
        root, transl = transform_smpl(cam_from_world, truth.root_orient, truth.transl,
                                      rest_root_joint(model, truth.betas))
        tracks.append({"track_id": k, "first_frame": 0, "num_frames": truth.num_frames, "root_orient": root,
                       "transl": transl, "body_pose": truth.body_pose, "betas": truth.betas,
                       "contacts": truth.contacts, "visible": np.ones(truth.num_frames, bool),
                       "keypoints": np.zeros((truth.num_frames, 17, 3))})
    return model, scene, tracks


def test_camera_scale_from_planted_feet():
    model, scene, tracks = camera_local_scene(vo_scale=2.5)
    estimate = estimate_camera_scale(model, tracks, {"world_from_cam": scene.cameras_vo.world_from_cam})
    # The truth's planted joints roll a little within a stance (heel to toe); the camera walks along its view, the
    # axis the estimator trusts least (depth): 1.2% off, within its stated uncertainty.
    assert estimate.value == pytest.approx(2.5, rel=0.02)
    feet, gait, ground = estimate.observations
    assert gait.reason == "no frame rate"  # the gait source needs the video's
    assert estimate.source == "planted feet" and 0 < feet.detail["bootstrap_sigma"] < 0.1
    assert abs(np.log(estimate.value / 2.5)) < 2 * estimate.sigma
    assert feet.frames > 20 and "map points" in ground.reason  # no odometry map here
    # A static camera (no baseline) gives no estimate.
    static = estimate_camera_scale(model, tracks, {"world_from_cam": np.tile(np.eye(4), (40, 1, 1))})
    assert static.sigma is None and static.source == "default"


def test_camera_scale_leaves_out_people_far_behind_the_nearest():
    """A walker three times as far as the scene's people, crossing at 1.5 m/s with every foot called planted (a
    crowd's far walker, whose contacts a monocular body gets wrong), would drag the planted feet's scale; it is no
    subject (m3c.vo.scale.scale_subjects), so the estimate is the one without him."""
    from m3c.ground.tracks import ground_contact_probabilities, track_frames
    from m3c.motion.scale import contact_joints_in_camera
    from m3c.vo.scale import scale_from_planted_feet

    model, scene, tracks = camera_local_scene(vo_scale=2.5)
    vo = {"world_from_cam": scene.cameras_vo.world_from_cam}
    far = dict(tracks[0], track_id=9, contacts=np.ones_like(tracks[0]["contacts"]))
    far["transl"] = 3.0 * np.asarray(tracks[0]["transl"]) + np.outer(np.arange(far["num_frames"]) / 30.0,
                                                                      [1.5, 0.0, 0.0])
    alone = estimate_camera_scale(model, tracks, vo)
    crowd = estimate_camera_scale(model, tracks + [far], vo)
    assert crowd.value == pytest.approx(alone.value, rel=1e-12) and crowd.sigma == pytest.approx(alone.sigma)
    everyone = tracks + [far]
    pooled = scale_from_planted_feet([contact_joints_in_camera(model, t) for t in everyone],
                                     [(ground_contact_probabilities(t) >= 0.5) & t["visible"][:, None]
                                      for t in everyone], [track_frames(t) for t in everyone],
                                     vo["world_from_cam"])
    assert abs(np.log(pooled.value / 2.5)) > 0.1  # what he would have done


def test_camera_scale_from_a_metric_depth_map_reads_the_map_points():
    """The depth-map observation scores the odometry's map points (not the people's contact points): map points on
    the scene's ground, in VO units, and depth maps holding their true metric depth at their pixels give the
    true scale exactly (each vote is metric depth / VO depth)."""
    from m3c.camera import project, to_camera

    model, scene, tracks = camera_local_scene(vo_scale=2.5)
    vo = scene.cameras_vo.world_from_cam
    centre = np.concatenate([t.transl for t in scene.truth]).mean(axis=0)
    gx, gz = np.meshgrid(np.linspace(-4, 4, 17), np.linspace(-4, 4, 17))
    ground = np.stack([gx.ravel() + centre[0], np.zeros(gx.size), gz.ravel() + centre[2]], axis=1)
    points = ground / 2.5  # the map in VO units
    width, height = scene.image_size
    maps = np.zeros((len(vo), height, width))
    for t in range(len(vo)):
        x = to_camera(points, vo[t])
        u, v = np.round(project(x, scene.cameras_vo.intrinsics)).astype(int).T
        inside = (x[:, 2] > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        maps[t, v[inside], u[inside]] = 2.5 * x[inside, 2]
    estimate = estimate_camera_scale(model, tracks, {"world_from_cam": vo, "points": points},
                                     depth={"available": True, "metric": True, "depth": maps},
                                     intrinsics=scene.cameras_vo.intrinsics)
    depth = next(o for o in estimate.observations if o.source == "depth map")
    assert depth.usable() and depth.value == pytest.approx(2.5, rel=1e-9)
    # The map's ground the ground source measured against (the plane y = 0 of the VO frame) is handed on.
    nx, ny, nz, d = estimate.to_dict()["ground_plane"]
    assert abs(ny) == pytest.approx(1.0, abs=1e-9) and abs(d) < 1e-9


def test_ground_and_lift_without_the_runner():
    """m3c.ground.world_frame.estimate_ground and m3c.motion.lift.lift_tracks on camera-local people seen by VO
    cameras at the true scale: the world they give is the scene's up to a shift along its up and a turn about it."""
    from m3c.ground import GroundParams
    from m3c.ground.world_frame import estimate_ground
    from m3c.motion.lift import lift_tracks

    model, scene, tracks = camera_local_scene(vo_scale=2.5)
    vo = scene.cameras_vo.world_from_cam
    ground = estimate_ground(model, tracks, vo, 2.5, GroundParams())
    assert ground["up_source"] == "ground" and ground["contact_points"] > 1000
    R = ground["world_from_vo"][:3, :3]
    assert np.degrees(np.arccos(np.clip((R @ [0.0, 1.0, 0.0])[1], -1, 1))) < 0.5  # the scene's up is y
    lifted = lift_tracks(model, tracks, ground["cameras"].world_from_cam(), ground["tracks"])
    heights = []
    for track, truth in zip(lifted, scene.truth):
        pose = np.concatenate([track["root_orient"][:, None], track["body_pose"]], axis=1)
        ours = model.joints(pose, track["betas"], track["transl"])
        true_pose = np.concatenate([truth.root_orient[:, None], truth.body_pose], axis=1)
        heights.append(ours[..., 1] - model.joints(true_pose, truth.betas, truth.transl)[..., 1])
        np.testing.assert_array_equal(track["ground_normal"], np.tile([0.0, 1.0, 0.0], (40, 1)))
    heights = np.concatenate([h.ravel() for h in heights])
    assert np.ptp(heights) < 0.02  # one shift for every joint of everyone: the ground is level
    assert abs(np.median(heights)) < 0.05  # the ground under the soles, the scene's near its lowest foot joint


def test_the_ground_is_the_odometry_maps_when_the_contacts_lie_on_it():
    """A person whose monocular depth drifts by 30% over the clip tilts a ground fitted to the contacts; the odometry
    map's ground plane (here: the one the clean contacts give, in VO units) keeps the world's up and the camera's
    height. A map plane 1 m away from the contacts is another surface: the contacts' ground is kept."""
    from m3c.ground import GroundParams
    from m3c.ground.world_frame import estimate_ground

    model, scene, tracks = camera_local_scene(vo_scale=2.5)
    vo = scene.cameras_vo.world_from_cam
    clean = estimate_ground(model, tracks, vo, 2.5, GroundParams())
    R, t = clean["world_from_vo"][:3, :3], clean["world_from_vo"][:3, 3]
    map_plane = np.r_[R[1], t[1] / 2.5]  # world y = 0 in the VO frame, VO units
    drifting = [dict(tr) for tr in tracks]
    drifting[0]["transl"] = tracks[0]["transl"] * (1.0 + 0.3 * np.arange(40) / 39)[:, None]

    def errors(ground):
        cams, truth = ground["cameras"].world_from_cam(), clean["cameras"].world_from_cam()
        tilt = np.degrees(np.arccos(np.clip((cams[:, 1, :3] * truth[:, 1, :3]).sum(-1), -1, 1))).max()
        return tilt, np.abs(cams[:, 1, 3] - truth[:, 1, 3]).max()

    contacts = estimate_ground(model, drifting, vo, 2.5, GroundParams())
    mapped = estimate_ground(model, drifting, vo, 2.5, GroundParams(), map_plane=map_plane)
    assert (contacts["ground_source"], mapped["ground_source"]) == ("contacts", "odometry map")
    tilted, on_map = errors(contacts), errors(mapped)
    # (arccos near 1 resolves about 1e-6 degrees)
    assert tilted[0] > 1.0 and on_map[0] < 1e-5 and on_map[1] < 1e-6, (tilted, on_map)
    away = estimate_ground(model, drifting, vo, 2.5, GroundParams(), map_plane=map_plane + [0, 0, 0, 1.0 / 2.5])
    assert errors(away) == pytest.approx(tilted) and away["ground_source"] == "contacts"
    with pytest.raises(ValueError, match="map_plane must be 4 finite numbers"):
        estimate_ground(model, drifting, vo, 2.5, GroundParams(), map_plane=[0.0, 0.0, 0.0, 1.0])
    # The scene's vertical edges (the focal node's record: each sampled frame's up in its camera) hold the tilt
    # the drifting contacts lose; results say which prior held it.
    frames = [{"frame": t, "up": (vo[t, :3, :3].T @ R[1]).tolist()} for t in range(0, 40, 8)]
    held = estimate_ground(model, drifting, vo, 2.5, GroundParams(), scene={"informative": True, "frames": frames})
    assert held["ground_source"] == "contacts" and errors(held)[0] < 0.35 * tilted[0]  # 3.5 -> 1.0 degrees
    assert (held["tilt_prior"], contacts["tilt_prior"], mapped["tilt_prior"]) == ("scene", "people", None)


def test_patches_node_isolates_the_focused_person(tmp_path):
    from m3c.io.video import VideoWriter
    from m3c.nodes.load import save_outputs
    from m3c.nodes.records import decode_image
    from m3c.pipeline import PipelineConfig, run_pipeline
    from m3c.pipeline.cache import Cache

    # Person A (red, in front) and person B (blue) overlap; 3 identical frames.
    frame = np.full((80, 120, 3), 90, np.uint8)
    frame[15:76, 40:91] = (255, 0, 0)  # B: x 40..90, y 15..75 (BGR blue)
    frame[20:71, 20:51] = (0, 0, 255)  # A: x 20..50, y 20..70 (BGR red), drawn over B
    with VideoWriter(tmp_path / "v.mp4", 10.0, (120, 80)) as writer:
        for _ in range(3):
            writer.write(frame)
    boxes = np.array([[20, 20, 50, 70], [40, 15, 90, 75]] * 3, np.float32)
    square = process_boxes(boxes, (80, 120), 5.0)[0].astype(np.float32)  # as perception hands them over
    np.testing.assert_allclose(square[0], [5, 15, 65, 75])  # A padded to 15..55 x 15..75, squared to 60
    save_outputs(tmp_path / "detections", {"detections": {
        "frame": np.repeat(np.arange(3), 2), "box": boxes, "square": square,
        "score": np.tile([0.9, 0.8], 3).astype(np.float32)}})
    masks = encode_masks([(np.ones((51, 31), bool), 20, 20), (np.ones((61, 51), bool), 40, 15)] * 3)
    save_outputs(tmp_path / "masks", {"masks": masks})
    config = PipelineConfig.from_yaml(f"""
settings: {{visualize: true}}
nodes:
  frames: {{}}
  detections: {{type: load, config: {{path: {tmp_path / 'detections'}, outputs: [detections]}}}}
  masks: {{type: load, config: {{path: {tmp_path / 'masks'}, outputs: [masks]}}}}
  patches:
    inputs: {{video: frames.video, detections: detections.detections, masks: masks.masks}}
    config: {{size: 60, jpeg_quality: 100}}
""")
    out = tmp_path / "out"
    report = run_pipeline(config, out, {"video": tmp_path / "v.mp4"}, show_progress=False)
    key = dict((r.name, r.key) for r in report.records)
    patch = decode_image(Cache(out / "cache").load("patches", key["patches"])["patches"], 0).astype(int)
    # One source pixel per patch pixel here: patch (i, j) shows frame (5 + i, 15 + j).
    def at(x, y):
        return patch[y - 15, x - 5]
    assert np.abs(at(35, 45) - [0, 0, 255]).max() < 40  # A itself
    assert np.abs(at(60, 40) - [255, 255, 255]).max() < 40  # B's pixels outside A's mask: white
    assert np.abs(at(10, 20) - [90, 90, 90]).max() < 40  # background outside B's box: kept
    assert (out / "viz" / "patches" / "patches.jpg").is_file()


def test_perception_picture_draws_the_boxes_it_hands_over(tmp_path):
    import cv2

    from m3c.io.video import VideoWriter
    from m3c.nodes.perception import PerceptionNode

    with VideoWriter(tmp_path / "v.mp4", 10.0, (120, 80)) as writer:
        for _ in range(3):
            writer.write(np.full((80, 120, 3), 90, np.uint8))

    class Context:
        def source(self, name):
            return str(tmp_path / "v.mp4")

    video = {"frame_ids": np.arange(3), "start": 0, "stop": 3, "step": 1}
    box = np.array([[30, 20, 50, 60], [30, 20, 50, 60], [70, 10, 100, 40]], np.float32)
    detections = {"frame": np.array([0, 1, 1]), "box": box,
                  "square": process_boxes(box, (80, 120), 5.0)[0].astype(np.float32)}
    paths = PerceptionNode("perception").visualize(Context(), {"video": video}, {"detections": detections}, tmp_path)
    assert [p.name for p in paths] == ["boxes_frame00001.jpg"]  # the frame with the most people
    picture = cv2.imread(str(paths[0])).astype(int)
    assert np.abs(picture[40, 30] - [0, 200, 0]).max() < 60  # the first person's tight box, green
    x0 = int(round(float(detections["square"][1, 0])))
    assert np.abs(picture[40, x0] - [0, 0, 255]).max() < 60  # its square box, red
    assert np.abs(picture[5, 5] - [90, 90, 90]).max() < 20  # nothing drawn elsewhere


def test_a_camera_the_odometry_saw_no_baseline_for_is_rotation_only(monkeypatch):
    """The odometry's static_camera (it never moved enough to initialise: translation zero, rotation fitted) makes
    the cameras rotation_only, so the scale node reads no scale from them and m3c info says still or rotating (the
    real benchmark's still cameras were reported as a default scale of a moving camera)."""
    from m3c.io.results import _camera_motion
    from m3c.nodes.scale import ScaleNode
    from m3c.nodes.vo import VisualOdometryNode as VONode

    T = 12
    rotations = Rotation.from_rotvec(np.outer(np.linspace(0, 0.05, T), [0, 1, 0])).as_matrix()
    poses = np.tile(np.eye(4), (T, 1, 1))
    poses[:, :3, :3] = rotations
    points = np.random.default_rng(0).uniform(-1, 1, (50, 3)) + [0, 0, 5]
    for static in (True, False):
        out = {"world_from_cam": poses, "points": points, "source": "test", "fit": None, "static_camera": static}
        monkeypatch.setattr(VONode, "_patch_vo", lambda self, ctx, inputs, out=out: out)
        cameras = VONode("vo").run(FakeContext(), {"video": {"num_frames": T}})["cameras"]
        assert cameras.get("rotation_only", False) == static
    monkeypatch.setattr(VONode, "_patch_vo", lambda self, ctx, inputs: {**out, "static_camera": True})
    still = VONode("vo").run(FakeContext(), {"video": {"num_frames": T}})["cameras"]
    scale = ScaleNode("scale").run(FakeContext(), {"cameras": still, "tracks": {"tracks": []}})["scale"]
    assert scale["source"] == "rotation only" and scale["sigma"] is None
    assert _camera_motion({"static": False, "rotation_only": True}).startswith("still or rotating")
