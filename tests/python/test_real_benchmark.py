"""The real-footage benchmark (m3c.eval.real_benchmark) against truth computed here independently: the warp of
a rotating camera against a pinhole projection written out in numpy (and m3c.camera's), the calibration's
camera height and gravity by hand, the shipped .trc file's values, and the scoring of results that are the
truth."""

from pathlib import Path

import numpy as np
import pytest
from m3c.camera import project
from m3c.eval import real_benchmark as rb
from m3c.eval.multiview import PELVIS, TRC_TO_SMPL, load_multiview, read_trc

cv2 = pytest.importorskip("cv2", reason="the warp needs opencv-python-headless")

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "examples" / "pose2sim_single_person"
EUROC = Path("/work/shared/data/vo/euroc_V1_01_easy_micro")


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _blob_image(size, centre, sigma=2.0):
    W, H = size
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    image = 255.0 * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2 * sigma**2))
    return np.repeat(image[..., None], 3, axis=2).astype(np.uint8)


def _centroid(image):
    gray = image[..., 0].astype(np.float64)
    gray[gray < 20] = 0.0
    v, u = np.nonzero(gray)
    w = gray[v, u]
    return np.array([(u * w).sum() / w.sum(), (v * w).sum() / w.sum()])


@pytest.mark.parametrize("distortion", [(0.0, 0.0, 0.0, 0.0), (-0.2, 0.05, 0.001, -0.0005)])
def test_warp_puts_a_scene_point_where_the_rotated_camera_projects_it(distortion):
    src_size, K_src = (640, 480), np.array([[500.0, 0, 318.0], [0, 505.0, 243.0], [0, 0, 1]])
    out_size, out_k = (420, 360), np.array([380.0, 380.0, 210.0, 180.0])
    point = np.array([0.3, -0.2, 4.0])  # in the still (source) camera
    cam_from_src = _rx(np.radians(2.5)) @ _ry(np.radians(-4.0)) @ _rz(np.radians(1.5))
    # The source image: a blob where the (distorting) source lens puts the point (OpenCV's projection).
    src_px = cv2.projectPoints(point[None], np.zeros(3), np.zeros(3), K_src, np.array(distortion))[0][0, 0]
    image = _blob_image(src_size, src_px)
    warped = rb.warp_frame(image, K_src, distortion, cam_from_src, rb.intrinsics_matrix(out_k), out_size)
    # Where the rotated virtual pinhole camera sees the point, written out by hand.
    x, y, z = cam_from_src @ point
    expected = np.array([out_k[0] * x / z + out_k[2], out_k[1] * y / z + out_k[3]])
    np.testing.assert_allclose(project(cam_from_src @ point, out_k), expected, atol=1e-9)
    np.testing.assert_allclose(_centroid(warped), expected, atol=0.15)
    if not any(distortion):  # the pinhole case is the homography K_out R K_src^-1
        h = rb.warp_homography(K_src, cam_from_src, rb.intrinsics_matrix(out_k)) @ np.r_[src_px, 1.0]
        np.testing.assert_allclose(h[:2] / h[2], expected, atol=1e-9)


def test_rotation_matrix_is_rodrigues():
    v = np.array([0.3, -0.7, 0.2])
    np.testing.assert_allclose(rb.rotation_matrix(v), cv2.Rodrigues(v)[0], atol=1e-12)
    assert rb.rotation_angle_deg(rb.rotation_matrix(v)) == pytest.approx(np.degrees(np.linalg.norm(v)))


def test_rotation_paths():
    up = np.array([0.1, -0.9, -0.4])
    up /= np.linalg.norm(up)
    T = 60
    assert np.allclose(rb.rotation_path("still", T, 60.0, up), np.eye(3))
    pan = rb.rotation_path("pan", T, 60.0, up, amplitude_deg=2.0)
    # about gravity: the up direction stays put, the sweep is 2 A, first to last
    np.testing.assert_allclose(np.einsum("tij,j->ti", pan, up), np.tile(up, (T, 1)), atol=1e-12)
    assert rb.rotation_angle_deg(pan[0].T @ pan[-1]) == pytest.approx(4.0)
    tilt = rb.rotation_path("tilt", T, 60.0, up, amplitude_deg=4.0)
    np.testing.assert_allclose(tilt[:, :, 0], np.tile([1.0, 0, 0], (T, 1)), atol=1e-12)  # about the x axis
    assert rb.rotation_angle_deg(tilt).max() == pytest.approx(4.0, abs=0.05)
    shake = rb.rotation_angle_deg(rb.rotation_path("shake", T, 60.0, up, amplitude_deg=0.8))
    assert 0.2 < shake.max() < 1.5
    with pytest.raises(ValueError, match="orbit"):
        rb.rotation_path("orbit", T, 60.0, up)


def test_relative_rotation_errors_align_the_first_frames():
    R = np.stack([_ry(np.radians(a)) for a in (0.0, 1.0, 2.0)])
    true = np.tile(np.eye(4), (3, 1, 1))
    true[:, :3, :3] = R
    pred = true.copy()
    offset = _rx(0.7)  # another world: cancels
    pred[:, :3, :3] = offset @ R
    np.testing.assert_allclose(rb.relative_rotation_errors(pred, true), 0.0, atol=1e-6)
    pred[2, :3, :3] = offset @ _ry(np.radians(2.5))
    np.testing.assert_allclose(rb.relative_rotation_errors(pred, true), [0.0, 0.0, 0.5], atol=1e-6)


def test_fit_crop_keeps_every_rotated_frame_inside_the_source():
    K = np.array([[800.0, 0, 270.0], [0, 800.0, 480.0], [0, 0, 1]])
    rotations = rb.rotation_path("pan", 30, 60.0, np.array([0.0, -1.0, 0.0]), amplitude_deg=3.0)
    intrinsics, (W, H) = rb.fit_crop(K, (540, 960), rotations)
    assert intrinsics[0] == pytest.approx(400.0) and intrinsics[2:].tolist() == [W / 2, H / 2]
    assert W < 240 and H > 440  # the pan costs width (the corners move a little vertically too)
    for R in rotations[[0, 15, 29]]:
        mx, my = rb.warp_maps(K, np.zeros(4), R, rb.intrinsics_matrix(intrinsics), (W, H))
        assert mx.min() >= 0 and mx.max() <= 539 and my.min() >= 0 and my.max() <= 959


def _rodrigues_by_hand(v):
    theta = np.linalg.norm(v)
    k = v / theta
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.cos(theta) * np.eye(3) + np.sin(theta) * cross + (1 - np.cos(theta)) * np.outer(k, k)


def test_calibration_gives_the_camera_height_and_gravity():
    # cam_01 of Calib_qualisys.toml: rotation (Rodrigues) and translation, world -> camera, world Z up
    R = _rodrigues_by_hand(np.array([1.6882754799999993, 1.0483220499999997, -0.41955852000000016]))
    t = np.array([0.3211048899999996, 0.9563320600000009, 2.8907130499999996])
    centre = -R.T @ t
    seq = load_multiview(FOLDER)
    height, up = rb.camera_height_and_up(seq.cameras[0].cam_from_world)
    assert height == pytest.approx(centre[2], abs=1e-9) and height == pytest.approx(1.8965, abs=1e-3)
    np.testing.assert_allclose(up, R[:, 2], atol=1e-9)  # the world's Z in the camera: R's third column
    # a camera looking down at the person: gravity (-up) points down the image (+y) and forwards (+z)
    assert -up[1] > 0.5 and -up[2] > 0
    # the floor is Z = 0: the feet's lowest keypoints sit just above it, the head top some 1.6 m up
    feet = seq.keypoints[:, [seq.names.index(n) for n in ("LBigToe", "RBigToe", "LHeel", "RHeel")], 2]
    assert 0.0 < feet.min() < 0.05
    assert 1.5 < np.percentile(seq.keypoints[:, seq.names.index("Head"), 2], 95) < 1.8


def test_trc_reader_and_joint_mapping():
    names, trc, fps = read_trc(FOLDER / "S00_P00_T01_BalancingTrial_0-100.trc")
    assert fps == 60.0 and trc.shape == (100, 21, 3) and names[:3] == ["RHip", "RKnee", "RAnkle"]
    np.testing.assert_allclose(trc[0, 0], [-0.06497214796810755, 0.9015045550714222, -1.4005886926185436])
    seq = load_multiview(FOLDER)
    world = [-1.4005886926185436, -0.06497214796810755, 0.9015045550714222]  # (trc Z, trc X, trc Y)
    np.testing.assert_allclose(seq.keypoints[0, 0], world)
    assert {"LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "LShoulder", "RShoulder"} <= set(TRC_TO_SMPL)
    joints = seq.joints()
    assert joints.shape == (100, 13, 3)
    z = {n: joints[:, i, 2] for i, n in enumerate(TRC_TO_SMPL)}
    assert np.all(z["LShoulder"] > z["LHip"]) and np.all(z["LHip"] > z["LKnee"])
    assert np.mean(z["RKnee"] > z["RAnkle"]) == 1.0
    assert [list(TRC_TO_SMPL)[i] for i in PELVIS] == ["LHip", "RHip"]


def test_parse_sequences():
    assert rb.parse_sequences(["cam_01:pan", "cam_02:still"]) == [("cam_01", "pan"), ("cam_02", "still")]
    for bad in ("cam_01", "cam_01:orbit"):
        with pytest.raises(ValueError, match="CAMERA:MOTION"):
            rb.parse_sequences([bad])


def _perfect_results(truth, model):
    """results.npz arrays and results.json that are the truth, in M3C's world (y up, ground y = 0)."""
    T = len(truth.cam_from_world)
    m3c_from_calib = np.eye(4)
    m3c_from_calib[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # calibration Z up -> M3C y up
    world_from_cam = m3c_from_calib @ np.linalg.inv(truth.cam_from_world)
    joints = np.zeros((2, T, 24, 3))
    joints[0][:, list(TRC_TO_SMPL.values())] = truth.joints @ m3c_from_calib[:3, :3].T
    joints[1] = joints[0] + [3.0, 0.0, 0.0]  # a bystander
    keypoints = np.zeros((2, T, 17, 3))
    for p in range(2):
        hips = joints[p][:, [1, 2]] @ m3c_from_calib[:3, :3]  # back to the calibration's world
        cfw = truth.cam_from_world
        cam = np.einsum("tij,tkj->tki", cfw[:, :3, :3], hips) + cfw[:, None, :3, 3]
        keypoints[p, :, 11:13, :2] = cam[..., :2] / cam[..., 2:] * truth.intrinsics[:2] + truth.intrinsics[2:]
        keypoints[p, :, 11:13, 2] = 1.0
    arrays = {"frame_ids": np.arange(T), "world_from_cam": world_from_cam, "track_ids": np.array([4, 7]),
              "valid": np.ones((2, T), bool), "visible": np.ones((2, T), bool),
              "world_joints": joints[::-1].copy(), "keypoints_2d": keypoints[::-1].copy(),
              "intrinsics": np.tile(truth.intrinsics, (T, 1)), "betas": np.zeros((2, model.num_betas))}
    summary = {"camera": {"static": False, "scale_source": "rotation only", "intrinsics_source": "given"}}
    return summary, arrays


def test_results_that_are_the_truth_score_zero(synthetic_body_model):
    seq = load_multiview(FOLDER)
    truth = rb.sequence_truth(seq, seq.cameras[1], "pan", 20, (1080, 1920))
    assert truth.in_view == 1.0 and truth.cam_from_world.shape == (20, 4, 4)
    summary, arrays = _perfect_results(truth, synthetic_body_model)
    v = rb.score_sequence(synthetic_body_model, truth, summary, arrays)
    assert v["camera_height_m"] == pytest.approx(1.691, abs=1e-3)
    for key in ("camera_height_error_m", "tilt_error_deg", "rotation_error_deg", "camera_path_m",
                "hip_height_error_m", "ankle_height_error_m", "mpjpe", "pa_mpjpe", "pelvis_depth_error_m",
                "focal_error_pct"):
        assert v[key] == pytest.approx(0.0, abs=1e-4), key
    assert v["true_rotation_max_deg"] == pytest.approx(2 * rb.AMPLITUDE_DEG["pan"], abs=0.05)
    assert v["rotation_only_reported"] and v["camera_reported"] == "rotation only"
    assert v["person_frames"] == 20 and v["tracks"] == 2
    # a camera 0.2 m too high and a world turned 5 degrees about its x axis (a ground tilted by 5 degrees)
    tilted = dict(arrays, world_from_cam=arrays["world_from_cam"].copy())
    tilted["world_from_cam"][:, 1, 3] += 0.2
    tilted["world_from_cam"][:, :3, :3] = _rx(np.radians(5.0)) @ tilted["world_from_cam"][:, :3, :3]
    w = rb.score_sequence(synthetic_body_model, truth, summary, tilted)
    assert w["camera_height_error_m"] == pytest.approx(0.2, abs=1e-6)
    assert w["rotation_error_deg"] == pytest.approx(0.0, abs=1e-4)  # the world's own turn is aligned away
    assert w["tilt_error_deg"] == pytest.approx(5.0, abs=1e-6)


@pytest.mark.skipif(not EUROC.exists(), reason=f"{EUROC} not present (the EuRoC micro clip of /work/shared)")
def test_euroc_truth_is_read():
    frames, truth = rb.load_euroc(EUROC)
    assert frames.shape == (95, 480, 752) and frames.dtype == np.uint8
    np.testing.assert_allclose(truth["intrinsics"], rb.EUROC_INTRINSICS)
    R = truth["world_from_cam"][:, :3, :3]
    np.testing.assert_allclose(np.einsum("tji,tjk->tik", R, R), np.tile(np.eye(3), (95, 1, 1)), atol=1e-9)
    steps = np.linalg.norm(np.diff(truth["world_from_cam"][:, :3, 3], axis=0), axis=1)
    assert steps.sum() < 0.05  # the MAV sits on the ground in these frames


def test_missing_euroc_is_skipped_with_a_reason(tmp_path, synthetic_body_model):
    report = rb.RealBenchmarkReport(str(FOLDER), 10, [], None, f"{tmp_path / 'none'} not present", 0.0)
    assert "EuRoC: skipped" in report.text() and report.summary()["euroc_skipped"].endswith("not present")


@pytest.mark.slow
def test_end_to_end_on_one_short_sequence(tmp_path, open_model):
    report = rb.run_real_benchmark(open_model, FOLDER, tmp_path, ["cam_02:pan"], num_frames=20,
                                   intrinsics=("true",), euroc=tmp_path / "no_euroc", show_progress=False)
    (score,) = report.sequences
    assert not score.error, score.error
    assert score.values["frames"] == 20 and score.values["true_rotation_max_deg"] > 3.9
    assert np.isfinite(score.values["camera_height_error_m"]) and "mpjpe" in score.values
    assert report.euroc is None and "not present" in report.euroc_skipped
    assert "cam_02_pan" in report.text()


def test_the_command_line():
    from m3c.cli.evaluation import eval_real_benchmark
    from m3c.cli.parser import build_parser

    args = build_parser().parse_args(["eval", "real-benchmark", "--sequences", "cam_01:tilt", "--euroc", "x"])
    assert args.func is eval_real_benchmark and args.frames == 60 and args.intrinsics == "both"
    assert args.folder == "examples/pose2sim_single_person" and args.sequences == ["cam_01:tilt"]
    assert len(rb.parse_sequences(rb.DEFAULT_SEQUENCES)) == 10
