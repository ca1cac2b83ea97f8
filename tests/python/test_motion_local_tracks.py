"""m3c.motion.local_tracks without the runner: a track given by its crop camera lands where the same track given
by its translation does, both contact kinds are filled, and malformed tracks are refused with the track named."""

import numpy as np
import pytest

from m3c.motion.local_tracks import camera_translations, fill_gaps, local_tracks
from m3c.perception.boxes import full_to_crop_camera

INTRINSICS = np.array([900.0, 900.0, 320.0, 240.0])


def _track(rng, track_id=3, frames=(4, 5, 8)):
    n = len(frames)
    transl = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, n), rng.uniform(3, 6, n)])
    square = np.tile([100.0, 50.0, 300.0, 250.0], (n, 1)).astype(np.float32)
    return {"track_id": track_id, "frame": np.asarray(frames), "square": square,
            "keypoints": rng.uniform(0, 300, (n, 21, 3)).astype(np.float32), "pose": rng.normal(size=(n, 24, 3)),
            "betas": rng.normal(size=(n, 10)), "transl": transl,
            "contacts": rng.uniform(size=(n, 4)).astype(np.float32),
            "ground_contacts": rng.uniform(size=(n, 4)).astype(np.float32)}


def test_crop_camera_and_translation_give_one_track(rng):
    track = _track(rng)
    cropped = {k: v for k, v in track.items() if k != "transl"}
    cropped["crop_cam"] = full_to_crop_camera(track["transl"], track["square"], INTRINSICS)
    np.testing.assert_allclose(camera_translations(cropped, INTRINSICS), track["transl"], atol=1e-9)
    a, b = fill_gaps(track, INTRINSICS), fill_gaps(cropped, INTRINSICS)
    np.testing.assert_allclose(a["transl"], b["transl"], atol=1e-9)
    # Frames 6 and 7 lie between frames 5 and 8: a third and two thirds of the way.
    np.testing.assert_allclose(a["transl"][2:4], track["transl"][1] + np.outer([1 / 3, 2 / 3],
                                                                               track["transl"][2] - track["transl"][1]))
    for key in ("contacts", "ground_contacts"):
        expected = track[key][1] + (track[key][2] - track[key][1]) / 3
        np.testing.assert_allclose(a[key][2], expected, rtol=1e-6)
    np.testing.assert_array_equal(a["detection"], -np.ones(5, int))  # no detections table behind this track


def test_malformed_tracks_are_named(rng):
    track = _track(rng)
    with pytest.raises(ValueError, match="misses pose"):
        local_tracks([{k: v for k, v in track.items() if k != "pose"}], INTRINSICS)
    with pytest.raises(ValueError, match="track 3: keypoints has 2 rows, frame 3"):
        local_tracks([dict(track, keypoints=track["keypoints"][:2])], INTRINSICS)
    with pytest.raises(ValueError, match="track ids must be unique"):
        local_tracks([track, track], INTRINSICS)
    with pytest.raises(ValueError, match="track 3: give its camera as transl or crop_cam"):
        fill_gaps({k: v for k, v in track.items() if k != "transl"}, INTRINSICS)
    kept, dropped = local_tracks([track, _track(rng, 1, (0, 2))], INTRINSICS, min_visible_frames=3)
    assert [t["track_id"] for t in kept] == [3] and dropped == {1: 2}
