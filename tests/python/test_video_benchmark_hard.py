"""The video benchmark's hard suite (m3c.eval.video_benchmark.HARD_SUITE): its sequences are built as stated (a
near-still handheld camera within 0.3 m, the mocap played at 1/2 and 1/4 speed, a plain floor, degraded frames),
reproducibly for a seed, and the default set is what it was."""

from dataclasses import asdict

import cv2
import numpy as np
import pytest
from m3c.eval import video_benchmark as vb
from m3c.synth import SequenceSpec, make_video, setup_sequence
from m3c.synth.cameras import STILL_MAX_TRAVEL_M
from m3c.synth.people import CROWD_DISTANCE, CROWD_MIN_SPEED
from m3c.synth.sequence import DEGRADE, degrade_frame, slowed


@pytest.fixture(scope="module")
def model(open_model):
    return open_model


@pytest.fixture(scope="module")
def clips(mocap_clips):
    return mocap_clips


def _config(**kw):
    return vb.VideoBenchmarkConfig(suite="hard", num_frames=60, width=320, height=180, **kw)


def test_the_hard_suite_mixes_every_difficulty():
    specs = _config().specs()
    assert len(specs) == len(vb.HARD_SUITE) >= 8
    assert {s.camera for s in specs} >= {"still", "follow", "tracking", "handheld", "static", "pan", "orbit"}
    assert {s.slow_motion for s in specs} == {1.0, 2.0, 4.0}
    assert {s.floor for s in specs} == {"textured", "plain", "glossy"} and any(s.degrade for s in specs)
    assert all(s.num_frames == (120 if s.slow_motion == 4 else 60) for s in specs)
    assert len({s.name for s in specs}) == len(specs) and "slow4" in specs[3].name
    # The default suite's specs, and so its folders, are unchanged: no new field joins their key.
    default = vb.VideoBenchmarkConfig(num_frames=60).specs()
    assert [s.camera for s in default] == ["static", "pan", "follow", "tracking", "orbit", "handheld", "high"]
    for spec in default:
        key = spec.key()
        assert set(key) == set(asdict(spec)) - {"slow_motion", "floor", "degrade", "crowd"}
        assert spec.name == f"seq{spec.index:02d}_{spec.camera}_{spec.num_people}p"
    with pytest.raises(ValueError, match="suite"):
        vb.VideoBenchmarkConfig(suite="harder").validate()
    with pytest.raises(ValueError, match="slow_motion"):
        SequenceSpec(0, "still", 1, slow_motion=0.5).validate()
    with pytest.raises(ValueError, match="floor"):
        SequenceSpec(0, "still", 1, floor="marble").validate()
    with pytest.raises(ValueError, match="crowd"):
        SequenceSpec(0, "still", 1, crowd=-1).validate()
    # --only picks sequences by index; an index the set does not have is refused, naming the range.
    assert [s.index for s in _config(only=(9, 12)).specs()] == [9, 12]
    with pytest.raises(ValueError, match=f"0-{len(vb.HARD_SUITE) - 1}"):
        _config(only=(len(vb.HARD_SUITE),)).validate()
    # Crowds of 10-30 walkers, one behind a near-still camera.
    crowds = [s for s in specs if s.crowd]
    assert len(crowds) >= 3 and all(10 <= s.crowd <= 30 for s in crowds)
    assert any(s.camera == "still" for s in crowds) and all("crowd" in s.name for s in crowds)


def test_slowed_clip_shows_the_motion_at_a_fraction_of_its_speed(clips):
    clip = clips[0]
    for factor in (2.0, 4.0):
        slow = slowed(clip, factor)
        k = int(factor)
        assert slow.num_frames == (clip.num_frames - 1) * k + 1 and slow.fps == clip.fps
        np.testing.assert_allclose(slow.transl[::k], clip.transl, atol=1e-12)
        np.testing.assert_allclose(slow.body_pose[::k], clip.body_pose, atol=1e-9)
        # Between two frames: the midpoint of the translation.
        mid = slow.transl[k // 2::k][: clip.num_frames - 1]
        np.testing.assert_allclose(mid, 0.5 * (clip.transl[:-1] + clip.transl[1:]), atol=1e-12)
        speed = np.linalg.norm(np.diff(slow.transl[:, [0, 2]], axis=0), axis=1).mean() * clip.fps
        real = np.linalg.norm(np.diff(clip.transl[:, [0, 2]], axis=0), axis=1).mean() * clip.fps
        assert speed == pytest.approx(real / factor, rel=0.02)
    assert slowed(clip, 1.0) is clip


def test_hard_sequences_are_built_as_stated_and_reproducible(model, clips):
    specs = _config().specs()
    still = next(s for s in specs if s.camera == "still" and s.floor == "plain")
    setup = setup_sequence(model, clips, still)
    centres = setup.world_from_cam[:, :3, 3]
    travel = np.linalg.norm(centres - centres[0], axis=1).max()
    assert 0.02 < travel < STILL_MAX_TRAVEL_M and setup.camera_info["max_travel_m"] == pytest.approx(travel)
    assert 1.2 < centres[:, 1].mean() < 1.9
    # The person stays in view of the near-still camera.
    cam = np.einsum("tji,tj->ti", setup.world_from_cam[:, :3, :3], setup.joints[0, :, 0] - centres)
    u = setup.intrinsics[0] * cam[:, 0] / cam[:, 2] + setup.intrinsics[2]
    assert (cam[:, 2] > 0).all() and ((u > 0) & (u < still.width)).mean() > 0.95
    # A plain floor: one texture for every tile, with almost no contrast; the textured one has pebbles.
    floor = setup.scene.textures[0]
    assert all(t is floor for t in setup.scene.textures[:4]) and floor.std(axis=(0, 1)).max() < 0.02
    textured = setup_sequence(model, clips, next(s for s in specs if s.floor == "textured"))
    assert textured.scene.textures[0].std(axis=(0, 1)).max() > 0.04
    # Reproducible for a seed, different for another.
    again = setup_sequence(model, clips, still)
    np.testing.assert_array_equal(again.world_from_cam, setup.world_from_cam)
    np.testing.assert_array_equal(again.joints, setup.joints)
    other = setup_sequence(model, clips, _config(seed=1).specs()[1])
    assert not np.array_equal(other.world_from_cam, setup.world_from_cam)


def test_a_slow_motion_sequence_is_rendered_with_its_truth(model, clips, tmp_path):
    """Slow motion x2 at 30 fps: the truth says so, and the people move at half their real speed."""
    spec = SequenceSpec(5, "static", 1, num_frames=12, width=160, height=96, slow_motion=2.0, degrade=True)
    video = make_video(model, clips, spec, tmp_path)
    truth = video.truth()
    assert truth["slow_motion"] == 2.0 and truth["fps"] == 30.0 and video.meta()["spec"]["degrade"]
    cap = cv2.VideoCapture(str(video.video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 12 and cap.get(cv2.CAP_PROP_FPS) == pytest.approx(30.0)
    normal = setup_sequence(model, clips, SequenceSpec(5, "static", 1, num_frames=12, width=160, height=96))
    assert not np.allclose(normal.joints, truth["joints"])


def test_degraded_frames_blur_and_add_noise():
    rng = np.random.default_rng(0)
    image = np.zeros((64, 64, 3), np.uint8)
    image[:, 32:] = 200
    out = degrade_frame(image, rng).astype(float)
    flat = out[:, :20] - 0.0
    assert abs(np.clip(flat, 0, None).mean()) < DEGRADE["noise_levels"]  # clipped at 0 below
    assert out[:, 40:].std() == pytest.approx(DEGRADE["noise_levels"], rel=0.15)
    edge = out[:, 30:34].mean(axis=0).mean(axis=1)
    assert 20 < edge[1] < 180 and 20 < edge[2] < 180  # the step is smeared over the pixels beside it


def test_a_crowd_walks_through_the_view_without_touching_the_scene(model, clips, tmp_path):
    """Unscored walkers: in the mid-sequence camera's view at 3-25 m, walking, 0.5 m from the scored people,
    some in front of them; the scored people and the camera are those of the same sequence without a crowd."""
    spec = SequenceSpec(9, "still", 2, num_frames=40, width=320, height=180, crowd=15)
    setup = setup_sequence(model, clips, spec)
    plain = setup_sequence(model, clips, SequenceSpec(9, "still", 2, num_frames=40, width=320, height=180))
    np.testing.assert_array_equal(plain.world_from_cam, setup.world_from_cam)
    np.testing.assert_array_equal(plain.joints, setup.joints)
    assert 12 <= len(setup.crowd) <= 15
    mid = setup.world_from_cam[20]
    hfov = np.radians(setup.camera_info["hfov_deg"])
    scored = setup.joints[:, :, 0]
    nearest = np.linalg.norm((scored - mid[:3, 3])[..., [0, 2]], axis=-1).min()
    distances = []
    for walker in setup.crowd:
        pelvis = model.joints(walker.pose(), walker.betas, walker.transl)[:, 0]
        centre = pelvis[[0, -1]].mean(axis=0)
        cam = (centre - mid[:3, 3]) @ mid[:3, :3]
        distances.append(np.hypot(cam[0], cam[2]))
        assert cam[2] > 0 and abs(np.arctan2(cam[0], cam[2])) <= 0.45 * hfov + 1e-9
        speed = np.linalg.norm(pelvis[-1, [0, 2]] - pelvis[0, [0, 2]]) * spec.fps / (spec.num_frames - 1)
        assert speed >= 0.9 * CROWD_MIN_SPEED
        assert np.linalg.norm((pelvis - scored)[..., [0, 2]], axis=-1).min() >= 0.5
        lowest = model.forward(walker.pose(), walker.betas, walker.transl).vertices[:, :, 1].min(axis=1)
        assert np.abs(lowest).max() < 0.1  # walking on the ground, no jumps
    distances = np.array(distances)
    assert CROWD_DISTANCE[0] - 0.5 <= distances.min() and distances.max() <= CROWD_DISTANCE[1] + 0.5
    assert (distances < nearest).any() and (distances > nearest + 3).any()
    # Rendered: the walkers draw with their own ids after the people's; the truth keeps their joints apart.
    video = make_video(model, clips, spec, tmp_path)
    truth = video.truth()
    assert truth["crowd_joints"].shape == (len(setup.crowd), 40, 24, 3)
    assert truth["keypoints_2d"].shape[0] == 2 and len(video.meta()["crowd"]) == len(setup.crowd)
    ids = set(np.unique(setup.frame(20).ids)) - {-1}
    assert ids - {0, 1} and max(ids) < 2 + len(setup.crowd)
    again = setup_sequence(model, clips, spec)
    np.testing.assert_array_equal(again.crowd[0].transl, setup.crowd[0].transl)
