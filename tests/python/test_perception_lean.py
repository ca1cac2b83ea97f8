"""People leaned to the scene's vertical (m3c.perception.lean): the lean towards the camera against a hand-built
body, the turn's direction, a track fitted leaning away re-fitted to the truth's lean and depth from the true body's
2D keypoints, abstentions, and the node with and without the scene's up."""

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body import default_body_model
from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.nodes.lean import LeanNode
from m3c.perception.body import keypoint_regressor
from m3c.perception.lean import LeanConfig, releaned_track, towards_camera

K = np.array([900.0, 900.0, 480.0, 270.0])
PITCH = 30.0  # the camera looks this far down


@pytest.fixture(scope="module")
def model():
    return default_body_model()


def _camera_up(pitch=PITCH):
    """World up in a camera pitched `pitch` degrees down (OpenCV axes: y down, z forward)."""
    return Rotation.from_rotvec([np.radians(pitch), 0, 0]).apply([0.0, -1.0, 0.0])


def test_lean_towards_the_camera_of_hand_built_joints():
    up = np.array([0.0, -1.0, 0.0])  # a level camera
    joints = np.zeros((2, 24, 3))
    pelvis, neck = SMPL_JOINT_NAMES.index("pelvis"), SMPL_JOINT_NAMES.index("neck")
    joints[:, pelvis] = [0.0, 0.0, 5.0]
    angle = np.radians(20.0)
    joints[0, neck] = joints[0, pelvis] + 0.5 * np.array([0.0, -np.cos(angle), -np.sin(angle)])  # towards: -z
    joints[1, neck] = joints[1, pelvis] + 0.5 * np.array([np.sin(angle), -np.cos(angle), 0.0])  # sideways
    lean, axis = towards_camera(joints, up)
    assert lean == pytest.approx([20.0, 0.0], abs=1e-9)
    # A right-handed turn about the axis raises the lean by its angle (through the pelvis).
    turned = Rotation.from_rotvec(np.radians(7.0) * axis[0]).apply(joints[0] - joints[0, pelvis]) + joints[0, pelvis]
    assert towards_camera(turned[None], up)[0][0] == pytest.approx(27.0, abs=1e-9)


def _track(model, lean_error, frames=40, seed=0):
    """(the fitted track leaning lean_error degrees away from the camera, the true camera-frame translations): a
    person walking upright 5-7 m in front of a camera pitched PITCH degrees down, its 2D keypoints the true
    body's projection; the 'fit' is the true body turned about its pelvis and pushed along the line of sight until
    its projected height matches (what a monocular fit does with a wrong lean)."""
    rng = np.random.default_rng(seed)
    up = _camera_up()
    base = Rotation.from_rotvec([np.radians(PITCH), 0, 0])  # body frame (y up) -> camera, upright
    pose = np.zeros((frames, 24, 3))
    pose[:, 0] = (base * Rotation.from_euler("x", 180, degrees=True) *
                  Rotation.from_euler("y", rng.uniform(-60, 60), degrees=True)).as_rotvec()
    swing = np.sin(np.linspace(0, 4 * np.pi, frames))
    for joint, sign in (("left_hip", 1), ("right_hip", -1), ("left_shoulder", -1), ("right_shoulder", 1)):
        pose[:, SMPL_JOINT_NAMES.index(joint), 0] = 0.35 * sign * swing
    betas = np.zeros((frames, 10))
    ground_point = np.stack([np.linspace(-1.0, 1.0, frames), np.zeros(frames), np.linspace(5.0, 7.0, frames)], 1)
    transl = ground_point + 0.9 * up  # the pelvis about 0.9 m over a point in front of the camera
    regressor = keypoint_regressor(model, 17)
    true_kp = model.keypoints(regressor, pose, betas, transl)
    pixels = np.stack([K[0] * true_kp[..., 0] / true_kp[..., 2] + K[2],
                       K[1] * true_kp[..., 1] / true_kp[..., 2] + K[3], np.ones(true_kp.shape[:2])], axis=-1)
    joints = model.joints(pose, betas, transl)
    _, axis = towards_camera(joints, up)
    fitted_pose, fitted_transl = pose.copy(), transl.copy()
    for i in range(frames):
        turn = Rotation.from_rotvec(np.radians(-lean_error) * axis[i])
        fitted_pose[i, 0] = (turn * Rotation.from_rotvec(pose[i, 0])).as_rotvec()
        pelvis = model.joints(fitted_pose[i:i + 1], betas[i:i + 1], np.zeros((1, 3)))[0, 0]
        fitted_transl[i] = joints[i, 0] * 1.12 - pelvis  # its pelvis 12% further along the same ray
    track = {"track_id": 3, "frame": np.arange(frames), "keypoints": pixels, "pose": fitted_pose, "betas": betas,
             "transl": fitted_transl}
    return track, transl, np.tile(up, (frames, 1))


def test_a_track_fitted_leaning_away_is_refitted_to_the_truths_lean_and_depth(model):
    track, true_transl, up = _track(model, lean_error=15.0)
    before, _ = towards_camera(model.joints(track["pose"], track["betas"], track["transl"]), up)
    assert np.median(before) == pytest.approx(-15.0, abs=0.5)
    new, record = releaned_track(model, track, up, K)
    after, _ = towards_camera(model.joints(new["pose"], new["betas"], new["transl"]), up)
    assert record["refit"] and record["turn"] == pytest.approx(15.0, abs=0.5)
    assert abs(np.median(after)) < 0.3 and record["lean_after"] == pytest.approx(np.median(after))
    depth_error = np.median(new["transl"][:, 2] / true_transl[:, 2])
    assert abs(depth_error - 1.0) < 0.005, depth_error  # it started 12% too far
    assert record["reprojection_px"] < 0.1  # the true body's own keypoints: an exact fit exists
    assert new["keypoints"] is track["keypoints"] and new["track_id"] == 3  # the rest of the track kept


def test_small_and_large_leans_are_left_alone(model):
    track, _, up = _track(model, lean_error=1.0, frames=10)
    same, record = releaned_track(model, track, up, K)
    assert same is track and not record["refit"] and "leans" in record["reason"]
    track, _, up = _track(model, lean_error=40.0, frames=10)  # too far to be the landmarks' bias
    same, record = releaned_track(model, track, up, K)
    assert same is track and not record["refit"]
    track, _, up = _track(model, lean_error=-10.0, frames=10)  # leaning towards the camera: a person bending
    same, record = releaned_track(model, track, up, K)
    assert same is track and not record["refit"] and record["lean_before"] > 9.0
    with pytest.raises(ValueError, match="min_lean < max_lean"):
        LeanConfig(min_lean=30.0, max_lean=20.0).validate()


class _Context:
    log = logging.getLogger("test")

    def __init__(self, model):
        self._model = model

    def loaded(self, name):
        assert name == "body_model"
        return self._model


def test_the_node_refits_where_the_scene_gives_the_up_direction(model):
    track, true_transl, up = _track(model, lean_error=12.0)
    frames = len(track["frame"])
    cameras = np.tile(np.eye(4), (frames, 1, 1))  # a still camera: the odometry frame is the camera's
    scene = {"frames": [{"frame": f, "up": up[f].tolist()} for f in (0, 10, 20, 30)]}
    inputs = {"tracks": {"tracks": [track]}, "cameras": {"world_from_cam": cameras},
              "camera": {"intrinsics": K, "source": "given", "scene": scene}}
    out = LeanNode("lean").run(_Context(model), inputs)["tracks"]
    assert out["up_source"] == "scene" and out["lean"][0]["refit"] and out["lean"][0]["track_id"] == 3
    assert abs(np.median(out["tracks"][0]["transl"][:, 2] / true_transl[:, 2]) - 1.0) < 0.005
    # Without the scene's up (or turned off) the tracks pass through.
    bare = dict(inputs, camera={"intrinsics": K, "source": "given", "scene": None})
    passed = LeanNode("lean").run(_Context(model), bare)["tracks"]
    assert passed["tracks"][0] is track and passed["up_source"] is None
    off = LeanNode("lean", LeanConfig(enabled=False)).run(_Context(model), inputs)["tracks"]
    assert off["tracks"][0] is track
    # An up direction known only loosely forwards (the default focal length, a camera 30 degrees down) is not used.
    loose = dict(inputs, camera={"intrinsics": K, "source": "default", "scene": scene})
    assert LeanNode("lean").run(_Context(model), loose)["tracks"]["tracks"][0] is track
