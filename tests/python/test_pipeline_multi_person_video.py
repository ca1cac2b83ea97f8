"""The default pipeline on a real two-person clip from ../shared (glamr_basketball.mp4: static camera, one player
dribbling, one man standing). Its first 135 frames once ran a body fit's depth away (one track to 346 m, and later
in the clip a body to 0.5 m whose keypoints then lay behind the camera: a NaN objective and no result), and the
tracker split the player into five ids over the clip (dribbling, crouching, partial detections). Needs the
shared data folder (or $M3C_VIDEO_DIR, as test_perception_mediapipe) and MediaPipe; skips with the reason otherwise."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from m3c.cli import main
from m3c.io.results import load_results
from m3c.perception import PerceptionConfig, run_perception
from m3c.perception.mediapipe_pose import mediapipe_available

VIDEO_DIR = Path(os.environ.get("M3C_VIDEO_DIR", Path(__file__).resolve().parents[3] / "shared" / "data" / "video"))
CLIP = VIDEO_DIR / "multi_person" / "glamr_basketball.mp4"
NUM_FRAMES = 135  # perception is causal: these frames are tracked and fitted as in the whole clip

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not CLIP.is_file(), reason=f"needs the shared clip {CLIP}"),
              pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (pip install 'm3c[perception]')")]


def test_two_person_clip_finishes_with_finite_plausible_results(tmp_path):
    out = tmp_path / "out"
    code = main(["run", str(CLIP), "--out", str(out), "--static-camera", "--frames", f"0:{NUM_FRAMES}",
                 "--until", "results", "--no-progress", "-q"])
    assert code == 0
    summary, arrays = load_results(out, check=False)
    json.loads((out / "results.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert len(summary["tracks"]) == 2  # the standing man and the player, one id each
    # Every stage ran, but those that would repeat the objective before them (no network weights here).
    assert all(stage["status"] == "ok" or (stage["status"] == "skipped" and "the same objective" in stage["message"])
               for stage in summary["optimization"]["stages"])
    # The two people share nothing the stages free (the scale is held): each stage solved them apart.
    assert all(stage["parts"] == 2 for stage in summary["optimization"]["stages"] if stage["status"] == "ok")
    cams = arrays["world_from_cam"]
    lift_cams = arrays["lift_world_from_cam"]
    for p in range(len(arrays["track_ids"])):
        valid = arrays["valid"][p]
        assert np.isfinite(arrays["world_joints"][p][valid]).all()
        # Both people stay on the court, 5-20 m from the camera (a runaway fit put one at 346 m).
        lifted = np.linalg.norm(arrays["lift_world_transl"][p][valid] - lift_cams[valid, :3, 3], axis=1)
        assert lifted.max() < 40.0
        final = np.linalg.norm(arrays["world_joints"][p][valid][:, 0] - cams[valid, :3, 3], axis=1)
        assert 4.0 < np.median(final) < 20.0
    # The camera's height, within 0.5 m of what the scene says (the goal). Read off the first frame, not
    # from M3C: the court lines meet at a horizon 60 px above the image centre; against it the standing man's eyes
    # and ankles put the camera 2.05-2.25 m up (eye height 1.55-1.70 m) and the back wall's hoop (rim 3.05 m)
    # 2.35 m. The focal length and the ground's tilt come from the gym's straight edges (m3c.vo.vanishing).
    assert summary["camera"]["intrinsics_source"] == "scene"
    assert 900 < summary["camera"]["intrinsics"][0] < 1100  # the edges' orthogonality: about 1000 px
    assert abs(cams[0, 1, 3] - 2.2) < 0.5


def test_two_people_keep_one_identity_each_over_the_whole_clip():
    """Both people are in view in all 300 frames: one track each (the player was five), each covering the clip,
    each on its own side of the court (the man left of the image centre, the player right of it)."""
    result = run_perception(CLIP, PerceptionConfig())
    assert result.num_frames == 300
    assert len(result.tracks) == 2
    centres = [0.5 * (t.boxes[:, 0] + t.boxes[:, 2]) for t in result.tracks]
    man, player = (result.tracks[k] for k in np.argsort([np.median(c) for c in centres]))
    for track in (man, player):
        assert track.frame_ids[0] <= 2 and track.frame_ids[-1] >= 297
        assert len(track.frame_ids) >= 0.95 * result.num_frames
    assert (0.5 * (man.boxes[:, 0] + man.boxes[:, 2]) < 640).all()
    assert (0.5 * (player.boxes[:, 0] + player.boxes[:, 2]) > 640).all()
