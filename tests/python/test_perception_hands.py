"""Hands around a person's wrists (m3c.perception.hands): the crops, the matching of detected hands to wrists,
and MediaPipe Hands end to end on rendered close-ups of the open model's posed hand (skipped without
mediapipe), followed by the per-frame fit."""

import numpy as np
import pytest
from m3c.body import BodyModel, open_body_model_data
from m3c.body.hands import load_hand_model
from m3c.perception.hand_fit import LOWER, UPPER, SideModel, fit_hand
from m3c.perception.hands import crop_square, match_hands, person_side, wrist_crop
from scipy.spatial.transform import Rotation


def coco(wrists: dict, elbows: dict) -> np.ndarray:
    keypoints = np.zeros((17, 3))
    for side, (w, e) in ((s, (wrists[s], elbows[s])) for s in wrists):
        keypoints[9 if side == "left" else 10] = [*w, 0.9]
        keypoints[7 if side == "left" else 8] = [*e, 0.9]
    return keypoints


def fake_hand(wrist, size=20.0) -> np.ndarray:
    return np.asarray(wrist, dtype=float) + size * np.linspace(0, 1, 21)[:, None] * np.array([1.0, 0.2])


def test_wrist_crop_follows_the_forearm():
    keypoints = coco({"left": (100.0, 100.0)}, {"left": (60.0, 100.0)})
    box, reach = wrist_crop(keypoints, "left")
    assert reach == pytest.approx(40.0)
    np.testing.assert_allclose(box, [114 - 40, 100 - 40, 114 + 40, 100 + 40])
    assert wrist_crop(keypoints, "right") is None  # not confident
    # A forearm pointing at the camera looks short: the torso sets the crop.
    keypoints[[5, 6, 11, 12]] = [[90, 0, 1], [50, 0, 1], [90, 200, 1], [50, 200, 1]]
    keypoints[7] = [98, 100, 0.9]
    _, reach = wrist_crop(keypoints, "left")
    assert reach == pytest.approx(100.0)


def test_crop_square_maps_pixels_back():
    frame = np.zeros((100, 120, 3), np.uint8)
    frame[30, 40] = 255
    box = np.array([20.5, 10.5, 60.5, 50.5])  # 40 px square, pixel edges
    crop, scale = crop_square(frame, box, size=40)
    assert scale == pytest.approx(1.0)
    i, j = np.unravel_index(np.argmax(crop[..., 0]), crop.shape[:2])
    np.testing.assert_allclose(box[:2] + (np.array([j, i]) + 0.5) * scale, [40, 30])
    assert crop[0, 0, 0] == 0 and crop.shape == (40, 40, 3)


def test_matching_by_distance_and_handedness():
    wrists = {"left": np.array([100.0, 100.0]), "right": np.array([200.0, 100.0])}
    forearms = {"left": 40.0, "right": 40.0}
    left, right = fake_hand(wrists["left"] + 3), fake_hand(wrists["right"] - 3)
    assert person_side("Left") == "right" and person_side("Right") == "left"  # MediaPipe's mirrored labels
    # Each crop sees both hands; the nearest with the right handedness wins.
    candidates = {"left": [(right, "Left", 0.9), (left, "Right", 0.9)],
                  "right": [(left, "Right", 0.9), (right, "Left", 0.9)]}
    matched = match_hands(candidates, wrists, forearms)
    np.testing.assert_allclose(matched["left"][0], left)
    np.testing.assert_allclose(matched["right"][0], right)
    # Too far from the wrist: no match.
    assert match_hands({"left": [(fake_hand([180.0, 100.0]), "Right", 0.9)]}, wrists, forearms) == {}
    # Handedness breaks a near tie.
    near = fake_hand(wrists["left"] + 5)
    other = fake_hand(wrists["left"] - 4)
    matched = match_hands({"left": [(other, "Left", 0.95), (near, "Right", 0.95)]}, wrists, forearms)
    np.testing.assert_allclose(matched["left"][0], near)
    # One hand between the wrists, found in both crops, goes to one of them only.
    middle = {"left": np.array([100.0, 100.0]), "right": np.array([120.0, 100.0])}
    shared = fake_hand([104.0, 100.0])
    matched = match_hands({"left": [(shared, "Right", 0.9)], "right": [(shared, "Right", 0.9)]}, middle,
                          forearms)
    assert list(matched) == ["left"]


@pytest.fixture(scope="module")
def engine():
    pytest.importorskip("mediapipe")
    from m3c.perception.hands import MediaPipeHands

    hands = MediaPipeHands()
    yield hands
    hands.close()


def test_mediapipe_finds_and_fits_the_rendered_hand(engine):
    import cv2
    from m3c.perception.hands import detect_hands
    from m3c.synth.hands import render_hand_scene
    from test_perception_hand_fit import procrustes_errors

    model = BodyModel(open_body_model_data())
    hand = load_hand_model()
    rng = np.random.default_rng(3)
    side_model = SideModel(hand, np.zeros(10), "left")
    good, errors = 0, []
    for trial in range(4):
        dofs = np.zeros(len(LOWER)) if trial == 0 else rng.uniform(0.4 * LOWER, 0.4 * UPPER)
        scene = render_hand_scene(model, dofs, hand=hand)
        landmarks = detect_hands(engine, cv2.cvtColor(scene.image, cv2.COLOR_BGR2RGB), scene.keypoints)
        if not np.isfinite(landmarks[0, 0, 0]):
            continue
        size = np.linalg.norm(scene.hand_pixels[0, 0] - scene.hand_pixels[0, 12])
        # MediaPipe's landmarks sit on the rendered hand (its joints are not MakeHuman's exactly); it may get
        # a hand wrong now and then (a rendered hand is not a photograph).
        if np.median(np.linalg.norm(landmarks[0, :, :2] - scene.hand_pixels[0], axis=1)) > 0.3 * size:
            continue
        good += 1
        fit = fit_hand(side_model, landmarks[0], scene.wrist_rotation[0], scene.wrist_position[0],
                       scene.world_from_cam, scene.intrinsics)
        wrist = scene.wrist_rotation[0] @ Rotation.from_rotvec(fit.wrist_correction).as_matrix()
        estimate = side_model.landmarks(fit.dofs[None], wrist[None], scene.wrist_position[0])[0]
        errors.append(procrustes_errors(estimate, scene.hand_keypoints_in_world[0]).mean())
    assert good >= 3
    assert np.mean(errors) < 0.025  # metres per hand point after Procrustes on the hand
