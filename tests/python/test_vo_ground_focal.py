"""A still camera's focal length from the people's planted feet and the scene's vertical vanishing point
(m3c.vo.ground_focal), against the camera the points were made with: exact on exact points at any tilt and roll,
whatever each person's size error or the vanishing point's sign; within a few percent under depth and pixel
noise; not informative for a level camera or people who keep one distance; and the focal node's still-camera
path, on a rendered scene with vertical edges only and bodies standing on its ground."""

import logging
import math

import numpy as np
import pytest

from m3c.body.joint_names import CONTACT_JOINTS
from m3c.body.open_model import default_body_model
from m3c.io.video import VideoWriter
from m3c.nodes.focal import FocalNode
from m3c.pipeline.progress import Progress
from m3c.vo.ground_focal import (GroundFocalConfig, focal_from_planted_feet, person_focal, planted_points,
                                 scene_vertical)
from m3c.vo.synthetic import built_scene_edges, look_rotation
from m3c.vo.vanishing import FrameLines, SceneCamera


def _camera_up(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The world's up direction in a camera (OpenCV axes, y down) pitched down by pitch_deg, rolled by roll_deg."""
    t, r = math.radians(pitch_deg), math.radians(roll_deg)
    up = np.array([0.0, -math.cos(t), -math.sin(t)])
    rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return rz @ up


def _walk(up, height, rng, frames=150, near=3.0, far=11.0, across=2.5):
    """Camera points (frames, 3) of one foot planted on the ground up . P = -height along a path wandering in
    depth between near and far metres and across +-across."""
    forward = np.array([0.0, 0.0, 1.0]) - up[2] * up
    forward /= np.linalg.norm(forward)
    side = np.cross(up, forward)
    t = np.linspace(0, 1, frames)
    phase = rng.uniform(0, 2 * np.pi, 2)
    depth = near + (far - near) * 0.5 * (1 + np.sin(2 * np.pi * t + phase[0]))
    lateral = across * np.sin(3 * np.pi * t + phase[1])
    return -height * up + depth[:, None] * forward + lateral[:, None] * side


def _observe(points, focal):
    """(centred pixels, q = focal / depth) of camera points."""
    return focal * points[:, :2] / points[:, 2:], focal / points[:, 2]


def _vertical(up, focal):
    return np.array([up[0], up[1], up[2] / focal])


@pytest.mark.parametrize("pitch, roll, focal", [(10.0, 0.0, 800.0), (6.0, 4.0, 1300.0), (-8.0, -3.0, 650.0),
                                                (25.0, 1.0, 1000.0)])
def test_exact_points_give_the_exact_focal(pitch, roll, focal, rng):
    up = _camera_up(pitch, roll)
    people = []
    for height in (1.5, 1.5 + 0.08):  # an ankle joint and a toe joint: parallel planes, one focal length
        pixels, q = _observe(_walk(up, height, rng), focal)
        people.append((pixels, q, np.arange(len(q))))
    estimate = focal_from_planted_feet(people, _vertical(up, focal), default=1101.0)
    assert estimate.informative and estimate.measured == pytest.approx(focal, rel=1e-6)
    assert estimate.log_sigma < 1e-6
    # Fused with the default as the prior: the inverse-variance mean in log(focal), the bias floor in the variance.
    config = GroundFocalConfig()
    w_prior, w_meas = 1 / config.prior_log_sigma ** 2, 1 / (estimate.log_sigma ** 2 + config.bias_log_sigma ** 2)
    fused = math.exp((w_prior * math.log(1101.0) + w_meas * math.log(focal)) / (w_prior + w_meas))
    assert estimate.focal == pytest.approx(fused, rel=1e-9)
    # A person's size error scales their q: their own line's slope and intercept alike, the same focal length.
    # The vanishing point's homogeneous sign does not matter either.
    sized = [(pixels, 1.3 * q, t) for pixels, q, t in people]
    again = focal_from_planted_feet(sized, -_vertical(up, focal), default=1101.0)
    assert again.measured == pytest.approx(focal, rel=1e-6)


def test_noisy_people_give_the_focal_within_a_few_percent(rng):
    focal, up = 800.0, _camera_up(8.0, 1.5)
    people = []
    for _ in range(3):
        points = _walk(up, 1.55, rng)
        pixels, q = _observe(points, focal)
        # Monocular depth errs by about 5%, slowly over time (a block of frames shares its error), pixels by 1.5.
        drift = np.repeat(rng.normal(0, 0.05, len(q) // 15 + 1), 15)[:len(q)]
        people.append((pixels + rng.normal(0, 1.5, pixels.shape), q * np.exp(drift + rng.normal(0, 0.02, len(q))),
                       np.arange(len(q))))
    estimate = focal_from_planted_feet(people, _vertical(up, focal), default=1101.0)
    assert estimate.informative
    assert abs(math.log(estimate.measured / focal)) < max(0.05, 3 * estimate.log_sigma)
    assert 0.005 < estimate.log_sigma < 0.15
    assert focal < estimate.focal < 1101.0 and abs(estimate.focal - focal) < abs(estimate.focal - 1101.0)
    assert len(estimate.people) == 3 and all(p["points"] == 150 for p in estimate.people)
    assert "3 people" in estimate.message
    summary = estimate.summary()
    assert summary["informative"] and summary["measured"] == estimate.measured
    # The same people under a gate tighter than their log-sigma: measured alike, the default kept, and said why.
    strict = focal_from_planted_feet(people, _vertical(up, focal), default=1101.0,
                                     config=GroundFocalConfig(max_log_sigma=0.5 * estimate.log_sigma))
    assert not strict.informative and strict.focal == 1101.0 and strict.measured == pytest.approx(estimate.measured)
    assert "not informative" in strict.message


def test_a_level_camera_or_one_distance_tells_nothing(rng):
    focal = 900.0
    up = _camera_up(0.5, 0.0)
    pixels, q = _observe(_walk(up, 1.5, rng), focal)
    level = focal_from_planted_feet([(pixels, q, np.arange(len(q)))], _vertical(up, focal), default=1101.0)
    assert not level.informative and level.focal == 1101.0 and "level" in level.message
    # A tracking shot: the person keeps one distance (only the pixel noise moves the feet along the vertical).
    up = _camera_up(8.0, 0.0)
    points = _walk(up, 1.5, rng, near=6.0, far=6.0)
    pixels, q = _observe(points, focal)
    noisy = [(pixels + rng.normal(0, 1.0, pixels.shape), q * np.exp(rng.normal(0, 0.03, len(q))),
              np.arange(len(q)))]
    estimate = focal_from_planted_feet(noisy, _vertical(up, focal), default=1101.0)
    assert not estimate.informative and estimate.focal == 1101.0
    exact = [(pixels, q, np.arange(len(q)))]  # exactly one distance and no roll: no line at all
    focal_found, sigma = person_focal(pixels, q, np.arange(len(q)), _vertical(up, focal), GroundFocalConfig(),
                                      np.random.default_rng(0))
    assert focal_found is None and sigma == math.inf
    assert not focal_from_planted_feet(exact, _vertical(up, focal), default=1101.0).informative
    # Too few planted points: nothing measured, and the message counts them.
    few = focal_from_planted_feet([(pixels[:10], q[:10], np.arange(10))], _vertical(up, focal), default=1101.0)
    assert not few.informative and few.measured is None and "10 points" in few.message


def test_bad_input_and_settings_are_named():
    with pytest.raises(ValueError, match="default focal length"):
        focal_from_planted_feet([], np.array([0.0, -1.0, 0.001]), default=0.0)
    with pytest.raises(ValueError, match="vertical"):
        focal_from_planted_feet([], np.array([0.0, 0.0, 1.0]), default=1000.0)
    with pytest.raises(ValueError, match="vertical"):
        focal_from_planted_feet([], np.array([np.nan, -1.0, 0.001]), default=1000.0)
    with pytest.raises(ValueError, match="resamples"):
        GroundFocalConfig(resamples=2)
    with pytest.raises(ValueError, match="enclose"):
        GroundFocalConfig(low=1.2)
    with pytest.raises(ValueError, match="bias_log_sigma"):
        GroundFocalConfig(bias_log_sigma=-1.0)


def test_scene_vertical_needs_frames_that_agree():
    def frame(k, x):  # a vertical vanishing point far below the image (a camera looking down)
        v = np.array([x, 1.0, 0.12])
        return FrameLines(k, v / np.linalg.norm(v), 20)

    agree = SceneCamera(960, 540, [frame(k, 0.001 * k) for k in range(5)])
    vertical, why = scene_vertical(agree, 1000.0)
    assert why == "" and vertical is not None
    # The pixel the vanishing point sits at, whatever the focal length it is read at.
    diagonal = math.hypot(960, 540)
    np.testing.assert_allclose(vertical[:2] / vertical[2], diagonal * np.array([0.002, 1.0]) / 0.12, rtol=1e-3)
    apart = SceneCamera(960, 540, [frame(k, 0.3 * k) for k in range(5)])
    vertical, why = scene_vertical(apart, 1000.0)
    assert vertical is None and "degrees apart" in why
    vertical, why = scene_vertical(SceneCamera(960, 540, [frame(0, 0.0)]), 1000.0)
    assert vertical is None and "1 sampled frames" in why


class _Context:
    def __init__(self, video_path):
        self.log = logging.getLogger("test")
        self._video = str(video_path)
        self._model = default_body_model()

    def source(self, name):
        return self._video

    def progress(self, desc, total):
        return Progress(desc, total, self.log, enabled=False)

    def loaded(self, name):
        assert name == "body_model"
        return self._model


def _standing_track(model, track_id, ankles, frames):
    """A perception track whose planted left ankle (contact joint 0) lies at `ankles` (n, 3) in the camera."""
    n = len(ankles)
    pose, betas = np.zeros((n, 24, 3)), np.zeros((n, 10))
    offset = model.joints(pose[:1], betas[:1], np.zeros((1, 3)))[0, CONTACT_JOINTS[0]]
    contacts = np.zeros((n, 4), np.float32)
    contacts[:, 0] = 1.0
    return {"track_id": track_id, "frame": frames, "pose": pose, "betas": betas, "transl": ankles - offset,
            "contacts": contacts}


def test_planted_points_are_the_planted_ankles_seen_by_the_camera(rng):
    model = default_body_model()
    ankles = np.column_stack([rng.uniform(-1, 1, 6), rng.uniform(1, 1.5, 6), rng.uniform(3, 9, 6)])
    track = _standing_track(model, 1, ankles, np.arange(10, 16))
    track["contacts"][2, 0] = 0.2  # not planted in its third frame
    track["contacts"][:, 2:] = 1.0  # the toes' joints: planted, but not at the ankles' height (left out)
    [(pixels, q, frames)] = planted_points(model, [track, {"track_id": 2, "frame": np.arange(3)}], 1000.0, 0.5)
    keep = np.array([0, 1, 3, 4, 5])
    np.testing.assert_allclose(pixels, 1000.0 * ankles[keep, :2] / ankles[keep, 2:], atol=1e-6)
    np.testing.assert_allclose(q, 1000.0 / ankles[keep, 2], rtol=1e-9)
    np.testing.assert_array_equal(frames, 10 + keep)


def test_focal_node_takes_the_planted_feet_for_a_still_camera(tmp_path, rng):
    """A still camera pitched about 11 degrees down over poles (vertical edges; the scene's horizontal edges are
    ignored by a setting, so the scene alone cannot tell the focal length) and two people walking on its ground:
    the focal node reads the true focal length from them, fuses it with the default, and re-expresses the bodies."""
    width, height, focal, frames = 640, 360, 500.0, 60
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(0.2, -0.2, 0.03)
    image = built_scene_edges(width, height, [focal, focal, width / 2, height / 2], pose, seed=1)
    path = tmp_path / "still.mp4"
    with VideoWriter(path, 30.0, (width, height)) as writer:
        for _ in range(frames):
            writer.write(np.repeat(image[..., None], 3, axis=2))
    up = pose[:3, :3].T @ np.array([0.0, -1.0, 0.0])  # world y points down; the camera stands 1.6 m up
    model = _Context(path).loaded("body_model")
    default = float(np.hypot(width, height))
    tracks = []
    for k in range(2):
        ankles = _walk(up, 1.6 - 0.08, rng, frames=frames, near=3.0, far=9.0, across=1.5)
        ankles[:, 2] *= default / focal  # perception fitted the bodies at the default focal length
        tracks.append(_standing_track(model, k, ankles, np.arange(frames)))
    inputs = {"video": {"num_frames": frames, "width": width, "height": height, "frame_ids": np.arange(frames),
                        "start": 0, "stop": frames, "step": 1},
              "camera": {"intrinsics": np.array([default, default, width / 2, height / 2]), "source": "default"},
              "masks": None, "detections": None, "tracks": {"tracks": tracks}}
    config = FocalNode.Config(motion=False, scene={"min_horizontal": 100000})
    out = FocalNode("focal", config).run(_Context(path), inputs)
    camera = out["camera"]
    assert not camera["scene"]["informative"] and camera["source"] == "people"
    feet = camera["feet_focal"]
    assert feet["informative"] and feet["measured"] == pytest.approx(focal, rel=0.03)
    assert camera["intrinsics"][0] == pytest.approx(feet["focal"]) and focal < feet["focal"] < 0.8 * default
    for track, given in zip(out["tracks"]["tracks"], tracks, strict=True):
        np.testing.assert_allclose(track["transl"][:, 2], given["transl"][:, 2] * feet["focal"] / default)
    # A camera whose motion was searched and found moving, or a setting, leaves the people out.
    off = FocalNode("focal", FocalNode.Config(motion=False, planted_feet=False,
                                              scene={"min_horizontal": 100000})).run(_Context(path), inputs)
    assert off["camera"]["source"] == "default" and off["camera"]["feet_focal"] is None


def test_m3c_info_names_a_still_camera_and_the_peoples_focal_length():
    from m3c.io.results import _camera_motion, _focal_uncertainty

    feet = {"message": "the planted feet of 1 person put the focal length at 898 px (log-sigma 0.05)"}
    still = {"static": False, "focal_estimate": {"still": True, "informative": False}, "intrinsics_source": "people",
             "feet_focal": feet}
    assert _camera_motion(still).startswith("still") and feet["message"] in _focal_uncertainty(still)
    assert _camera_motion({**still, "static": True}) == "static"
    assert _camera_motion({"static": False, "focal_estimate": None}) == "moving"
