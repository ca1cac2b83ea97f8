"""Perception's hand-over (m3c.perception.handover): its tracks whole, and the same people frame by frame, checked
against the PerceptionResult they come from, row by row."""

import numpy as np

from m3c.perception.body import BodyFits
from m3c.perception.boxes import process_boxes
from m3c.perception.handover import hand_over
from m3c.perception.pipeline import PerceptionResult, PersonTrack
from m3c.perception.types import pack_mask

SIZE = (90, 160)  # height, width


def _track(rng, track_id, frames, status, keypoints=21, ground=False, masks=True):
    n = len(frames)
    x0 = rng.uniform(0, 100, n)
    y0 = rng.uniform(0, 40, n)
    boxes = np.stack([x0, y0, x0 + rng.uniform(10, 50, n), y0 + rng.uniform(20, 60, n)], axis=1)
    bodies = BodyFits(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 23, 3)),
                      rng.normal(size=(n, 10)), np.zeros(n), np.zeros((n, keypoints)), np.full(n, keypoints),
                      np.zeros(n, bool), list(status))
    mask_list = None
    if masks:
        mask_list = [(pack_mask(rng.uniform(size=(4 + i, 3 + i)) > 0.5), np.array([i, 2 * i, 3 + 2 * i, 4 + 3 * i]))
                     for i in range(n)]
    return PersonTrack(track_id, np.asarray(frames), boxes, rng.uniform(0.3, 1.0, n),
                       rng.uniform(0, 80, (n, keypoints, 3)), np.zeros((n, keypoints, 4)), bodies,
                       rng.uniform(size=(n, 4)), "neutral", {}, mask_list,
                       rng.uniform(size=(n, 4)) if ground else None)


def test_hand_over_keeps_tracks_whole_and_tables_aligned(rng):
    tracks = [_track(rng, 2, [0, 1, 2, 4], ["ok", "too_few_keypoints", "ok", "ok"], ground=True),
              _track(rng, 5, [1, 2, 3], ["ok", "ok", "ok"], keypoints=17, masks=False),
              _track(rng, 8, [3, 4], ["too_few_keypoints"] * 2)]  # no fitted frame: left out
    result = PerceptionResult("clip", 30.0, SIZE, np.array([100.0, 100.0, 80.0, 45.0]), 5, tracks, {}, {})
    out, detections, masks = hand_over(result, padding=3.0)

    assert [t["track_id"] for t in out] == [2, 5]
    first = out[0]
    valid = [0, 2, 3]  # the frames whose body fit succeeded
    np.testing.assert_array_equal(first["frame"], [0, 2, 4])
    np.testing.assert_array_equal(first["keypoints"], tracks[0].keypoints[valid].astype(np.float32))
    assert first["keypoints"].shape[1] == 21  # the foot points travel with the track
    np.testing.assert_array_equal(first["pose"], tracks[0].bodies.pose[valid])
    np.testing.assert_array_equal(first["transl"], tracks[0].bodies.transl[valid])
    np.testing.assert_array_equal(first["ground_contacts"], tracks[0].ground_contacts[valid].astype(np.float32))
    assert "ground_contacts" not in out[1] and out[1]["keypoints"].shape[1] == 17
    square = process_boxes(tracks[0].boxes[valid].astype(np.float32), SIZE, 3.0)[0].astype(np.float32)
    np.testing.assert_array_equal(first["square"], square)

    # The detections table: every handed-over person once, by frame then descending score, and each track's
    # detection indices point at its own rows.
    assert len(detections["frame"]) == len(masks) == 6
    order = np.lexsort((-detections["score"], detections["frame"]))
    np.testing.assert_array_equal(order, np.arange(6))
    for track in out:
        rows = track["detection"]
        np.testing.assert_array_equal(detections["frame"][rows], track["frame"])
        np.testing.assert_array_equal(detections["box"][rows], track["box"])
        np.testing.assert_array_equal(detections["square"][rows], track["square"])
        np.testing.assert_array_equal(detections["score"][rows], track["score"])
    # Masks follow their rows: track 2's frame-4 mask (its 4th entry), none for track 5.
    bits, h, w, x0, y0 = masks[out[0]["detection"][2]]
    (expected_bits, eh, ew), box = tracks[0].masks[3]
    np.testing.assert_array_equal(bits, expected_bits)
    assert (h, w, x0, y0) == (eh, ew, box[0], box[1])
    assert all(masks[r][1:3] == (0, 0) for r in out[1]["detection"])


def test_hand_over_of_nobody():
    result = PerceptionResult("clip", 30.0, SIZE, np.array([100.0, 100.0, 80.0, 45.0]), 5, [], {}, {})
    out, detections, masks = hand_over(result)
    assert out == [] and masks == []
    assert detections["frame"].shape == (0,) and detections["square"].shape == (0, 4)
