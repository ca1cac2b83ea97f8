"""The hands node (m3c.nodes.hands) on a short rendered video of the open model's posed left hand: MediaPipe
finds it around the wrist, the fit poses the fingers, results.npz stores them and the overlay draws them; and
--no-hands turns the node off."""

from __future__ import annotations

import contextlib
import types
from pathlib import Path

import numpy as np
import pytest
from m3c.body import default_body_model
from m3c.body.hands import WRIST_JOINTS, wrist_frames
from m3c.camera import WorldCameras
from m3c.nodes.hands import HandsNode, corrected_body_pose, track_hands
from scipy.spatial.transform import Rotation


class FakeContext:
    """What track_hands reads from a node's run context: the video source and progress bars."""

    def __init__(self, video: Path):
        self.video = video

    def source(self, name: str) -> Path:
        return self.video

    def progress(self, desc: str, total):
        return contextlib.nullcontext(types.SimpleNamespace(update=lambda *a: None))


@pytest.fixture(scope="module")
def model():
    return default_body_model()


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, model):
    """Three frames of the left hand closing, the camera still; the track's body and keypoints exact."""
    from m3c.io.video import VideoWriter
    from m3c.perception.hand_fit import FLEXION, NUM_DOFS
    from m3c.synth.hands import body_pose, render_hand_scene

    folder = tmp_path_factory.mktemp("hands_video")
    fingers = np.arange(NUM_DOFS) < 16  # the four fingers flex, the thumb stays
    scenes = [render_hand_scene(model, np.where(FLEXION & fingers, f, 0.0)) for f in (0.0, 0.2, 0.4)]
    path = folder / "hand.mp4"
    with VideoWriter(path, 10.0, (640, 480)) as writer:
        for scene in scenes:
            writer.write(scene.image)
    n = len(scenes)
    pose = body_pose()[0]
    track = {"track_id": 3, "first_frame": 0, "num_frames": n, "root_orient": np.zeros((n, 3)),
             "body_pose": np.tile(pose[1:], (n, 1, 1)), "betas": np.zeros(10), "transl": np.zeros((n, 3)),
             "keypoints": np.stack([s.keypoints for s in scenes])}
    cams = np.stack([s.world_from_cam for s in scenes])
    result = {"tracks": [track], "cameras": WorldCameras(cams[:, :3, :3], cams[:, :3, 3], 1.0).as_dict()}
    video = {"num_frames": n, "frame_ids": np.arange(n), "start": 0, "stop": n, "step": 1}
    return path, video, {"intrinsics": scenes[0].intrinsics}, result, scenes


def test_the_node_finds_fits_and_stores_the_hand(rendered, model):
    pytest.importorskip("mediapipe")
    from m3c.body.hands import load_hand_model
    from m3c.nodes.results import world_hand_keypoints

    path, video, camera, result, scenes = rendered
    hands = track_hands(FakeContext(path), model, load_hand_model(), video, camera, result, HandsNode.Config())
    assert hands["enabled"] and hands["frames"] == 3
    track = hands["tracks"][0]
    found = np.isfinite(track["hand_pose"][:, 0, 0, 0])
    assert found.sum() >= 2  # the left hand, in most frames
    assert not np.isfinite(track["hand_pose"][:, 1]).any()  # the right hand is out of view
    # The fitted hand lies on the rendered one: within 2.5 cm per point (the body is exact here).
    posed = corrected_body_pose(result["tracks"][0]["body_pose"], track["wrist_correction"])
    pose = np.concatenate([np.zeros((3, 1, 3)), posed], axis=1)
    points = world_hand_keypoints(model, pose, np.zeros(10), np.zeros((3, 3)), track["hand_pose"])
    for k in np.flatnonzero(found):
        error = np.linalg.norm(points[k, 0] - scenes[k].hand_keypoints_in_world[0], axis=1)
        assert np.mean(error) < 0.025
    # The overlay draws the fingers.
    from m3c.viz.scene import draw_hands

    frame = np.zeros((480, 640, 3), np.uint8)
    k = int(np.flatnonzero(found)[0])
    draw_hands(frame, [(points[k], 3)], scenes[k].world_from_cam, scenes[k].intrinsics)
    assert (frame.sum(axis=2) > 0).sum() > 200


def test_corrected_body_pose_turns_only_the_wrists(model):
    rng = np.random.default_rng(0)
    body_pose = rng.normal(0, 0.3, (4, 23, 3))
    correction = rng.normal(0, 0.2, (4, 2, 3))
    correction[1, 1] = np.nan  # no right hand in frame 1
    new = corrected_body_pose(body_pose, correction)
    changed = np.abs(new - body_pose).max(axis=(0, 2)) > 1e-9
    assert np.flatnonzero(changed).tolist() == [19, 20]
    np.testing.assert_allclose(new[1, 20], body_pose[1, 20])
    pose = np.concatenate([np.zeros((4, 1, 3)), body_pose], axis=1)
    new_pose = np.concatenate([np.zeros((4, 1, 3)), new], axis=1)
    before, _ = wrist_frames(model, pose, np.zeros(10))
    after, _ = wrist_frames(model, new_pose, np.zeros(10))
    for s in (0, 1):
        ok = np.isfinite(correction[:, s]).all(axis=1)
        expected = before[ok, s] @ Rotation.from_rotvec(correction[ok, s]).as_matrix()
        np.testing.assert_allclose(after[ok, s], expected, atol=1e-9)
    assert WRIST_JOINTS == {"left": 20, "right": 21}


def test_no_hands_turns_the_node_off():
    from m3c.cli.parser import build_parser
    from m3c.cli.pipeline import pipeline_config

    args = build_parser().parse_args(["run", "video.mp4", "--out", "out", "--no-hands"])
    config = pipeline_config(args)
    assert config.nodes["hands"].config["enabled"] is False
    default = pipeline_config(build_parser().parse_args(["run", "video.mp4", "--out", "out"]))
    assert default.nodes["hands"].config["enabled"] is True
    assert default.nodes["results"].inputs["hands"] == "hands.hands"
    assert default.nodes["overlay"].inputs["hands"] == "hands.hands"
    batch = build_parser().parse_args(["batch", "videos", "--out", "out", "--no-hands"])
    assert batch.no_hands
