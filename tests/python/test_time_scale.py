"""The video's time scale from the people's gait (m3c.motion.time_scale): procedural walkers and runners played at
1x, 2x and 4x slow motion (the frame rate unchanged), whose true factor the estimate must recover."""

import numpy as np
import pytest

from m3c.body import default_body_model
from m3c.eval.plausibility import track_plausibility
from m3c.motion.time_scale import RUN_CADENCE, WALK_CADENCE, estimate_time_scale, gait_time_scale


def _gait(model, strides_per_s, speed, seconds, fps=30.0, phase=0.4):
    """The procedural walker of m3c.eval.scenes at a known stride frequency, gliding along +z at `speed`."""
    from m3c.eval.scenes import walking_pose

    t = np.arange(round(seconds * fps)) / fps
    pose = np.zeros((len(t), 24, 3))
    pose[:, 1:] = walking_pose(2 * np.pi * strides_per_s * t + phase)
    transl = np.zeros((len(t), 3))
    transl[:, 2] = speed * t
    return model.joints(pose, np.zeros(model.num_betas), transl)


def _played(model, strides, speed, slow, real_seconds=2.5):
    """A gait of `strides` per second at `speed` (real time) played `slow` times slower at 30 fps."""
    return track_plausibility(_gait(model, strides / slow, speed / slow, real_seconds * slow), 30.0)


@pytest.fixture(scope="module")
def model():
    return default_body_model()


# (strides a second, speed m/s) in real time: walks at 108 and 114 steps a minute, runs at 168 and 156.
WALKS = ((0.9, 1.2), (0.95, 1.35))
RUNS = ((1.4, 4.0), (1.3, 3.2))


@pytest.mark.parametrize("slow", [1.0, 2.0, 4.0])
def test_walks_and_runs_give_their_slow_motion(model, slow):
    for (strides, speed), cadence in [(g, WALK_CADENCE[0]) for g in WALKS] + [(g, RUN_CADENCE[0]) for g in RUNS]:
        figures = _played(model, strides, speed, slow, real_seconds=3.0 if slow < 4 else 2.5)
        assert figures["step_rate_spm"] == pytest.approx(120 * strides / slow, rel=0.01)
        factor, sigma, gait = gait_time_scale(figures)
        assert gait == ("walking" if cadence == WALK_CADENCE[0] else "running")
        # The model's error is the person's cadence against the typical one: exact up to it.
        assert factor == pytest.approx(slow * cadence / (120 * strides), rel=0.01)
        assert abs(np.log(factor / slow)) < 2 * sigma and abs(factor / slow - 1) < 0.12
    tracks = [_played(model, s, v, slow) for s, v in WALKS + RUNS]
    estimate = estimate_time_scale(tracks)
    assert estimate["factor"] == pytest.approx(slow, rel=0.1) and len(estimate["tracks"]) == 4
    assert estimate["confident"] == (slow > 1) and estimate["log_sigma"] < 0.07
    if slow == 1.0:
        assert estimate["reason"] == "the people step at a normal rate"


def test_time_scale_after_slow_motion_was_applied(model):
    """--slow-motion 2 on a 2x clip: the figures are in real time, the people say nothing more is needed."""
    real = track_plausibility(_gait(model, 0.45, 0.6, 6.0), 60.0)  # 30 fps played 2x slow, times at 60 fps
    estimate = estimate_time_scale([real], applied=2.0)
    assert estimate["measured"] == pytest.approx(WALK_CADENCE[0] / 108, rel=0.01) and not estimate["confident"]
    assert estimate["factor"] == pytest.approx(2.0 * estimate["measured"], rel=1e-12)


def test_no_gait_no_time_scale(model):
    standing = np.repeat(_gait(model, 0.9, 1.2, 5.0)[:1], 150, axis=0)
    shuffle = track_plausibility(_gait(model, 0.45, 0.25, 6.0), 30.0)  # a slow, short step: a stroll, not slow motion
    estimate = estimate_time_scale([None, track_plausibility(standing, 30.0), shuffle])
    assert shuffle["step_length_legs"] < 0.4 and gait_time_scale(shuffle) is None
    assert estimate["factor"] == 1.0 and estimate["log_sigma"] is None and not estimate["confident"]
    assert "no track" in estimate["reason"]
    with pytest.raises(ValueError, match="slow motion"):
        estimate_time_scale([], applied=0.0)


def test_people_who_disagree_widen_the_factor(model):
    """One walker at 2x slow, one at normal speed (a wrong gait): the fused factor's uncertainty covers both."""
    tracks = [_played(model, 0.9, 1.2, 2.0), _played(model, 0.9, 1.2, 1.0)]
    estimate = estimate_time_scale(tracks)
    logs = np.log([t["factor"] for t in estimate["tracks"]])
    assert np.all(np.abs(logs - np.log(estimate["measured"])) < 2 * estimate["log_sigma"])
    assert not estimate["confident"]


def test_info_says_slow_motion_when_the_gait_is_sure(model):
    from m3c.io.results import _slow_gait_hint, _time_scale

    slow = _played(model, 0.9, 1.2, 2.0)
    estimate = estimate_time_scale([slow])
    line = _time_scale({"time_scale": estimate})[0]
    assert "slow motion likely" in line and f"--slow-motion {estimate['factor']:.2f}" in line
    assert "--slow-motion" in _slow_gait_hint(slow)
    normal = estimate_time_scale([_played(model, 0.9, 1.2, 1.0)])
    assert _time_scale({"time_scale": normal}) == ["time        the people step at a normal rate (x1.02 +-10% from "
                                                   "the gait of 1 track)"]
    assert _time_scale({"time_scale": estimate_time_scale([None])}) == [] and _time_scale({}) == []


def _image_keypoints(joints, heading, rng=None, drop=0.0):
    """COCO keypoints (n, 17, 3) of a body seen by a camera 6 m away, 1 m up, looking along +z (the body walks
    along `heading` in x-z): nose from the head, hips, knees and ankles; the rest unseen (NaN)."""
    c, s = np.cos(heading), np.sin(heading)
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    world = joints @ turn.T + [0.0, 0.0, 6.0]
    cam = world * [1, -1, 1] + [0, 1.0, 0]
    uv = 800 * cam[..., :2] / cam[..., 2:] + [480, 270]
    out = np.full((len(joints), 17, 3), np.nan)
    for coco, smpl in {0: 15, 11: 1, 12: 2, 13: 4, 14: 5, 15: 7, 16: 8}.items():
        out[:, coco, :2] = uv[:, smpl]
        out[:, coco, 2] = 0.9
    if rng is not None:
        out[..., :2] += rng.normal(0, 1.0, out[..., :2].shape)
        out[rng.uniform(size=len(out)) < drop, 15, 2] = 0.1  # an ankle missed now and then
    return out


@pytest.mark.parametrize("slow", [1.0, 2.0, 4.0])
@pytest.mark.parametrize("heading", [0.0, np.pi / 2])  # away from the camera (rows), across it (columns)
def test_image_step_rate_times_the_ankles(model, slow, heading):
    from m3c.eval.plausibility import image_step_rate

    strides = 0.9 / slow  # 108 steps a minute in real time
    joints = _gait(model, strides, 1.2 / slow, 3.0 * slow)
    rate = image_step_rate(_image_keypoints(joints, heading, np.random.default_rng(0), drop=0.1), 30.0)
    # Walking away, the ankles' image offset shrinks with depth (an amplitude the sinusoid fit does not model): a
    # few percent, against the 15% spread of people's cadence.
    assert rate == pytest.approx(120 * strides, rel=0.05)
    factor, sigma, gait = gait_time_scale({"step_rate_spm": None, "image_step_rate_spm": rate})
    assert gait == "stepping (image)" and factor == pytest.approx(slow * 110 / 108, rel=0.05)
    assert abs(np.log(factor / slow)) < sigma


def test_image_step_rate_needs_ankles_that_alternate(model):
    from m3c.eval.plausibility import image_step_rate

    standing = np.repeat(_gait(model, 0.9, 1.2, 5.0)[:1], 150, axis=0)
    rng = np.random.default_rng(1)
    assert image_step_rate(_image_keypoints(standing, 0.0, rng), 30.0) is None
    unseen = _image_keypoints(_gait(model, 0.9, 1.2, 5.0), 0.0)
    unseen[::2, 16, 2] = 0.0  # half the frames without the right ankle
    unseen[1::4, 15, 2] = 0.0
    assert image_step_rate(unseen, 30.0) is None
    with pytest.raises(ValueError, match="shape"):
        image_step_rate(np.zeros((10, 17, 2)), 30.0)


def test_image_gait_alone_is_possible_not_confident(model):
    """The 2D ankles alone, stepping 2x slow: reported as possible slow motion, not confident (a walk that stops
    can look like a slow stride in the image); with a world gait beside it, confident."""
    from m3c.io.results import _time_scale

    image_only = {"step_rate_spm": None, "image_step_rate_spm": 54.0}
    estimate = estimate_time_scale([image_only])
    assert estimate["possible"] and not estimate["confident"]
    assert estimate["factor"] == pytest.approx(110 / 54, rel=1e-12) and estimate["log_sigma"] == 0.15
    assert _time_scale({"time_scale": estimate})[0].startswith("time        slow motion possible")
    both = estimate_time_scale([image_only, _played(model, 0.9, 1.2, 2.0)])
    assert both["confident"] and both["factor"] == pytest.approx(2.04, rel=0.03)


def test_stride_fit_stays_near_its_peak():
    """A flat least-squares fit near the spectrum's peak once extrapolated to a negative rate (a walk that stops:
    the hard suite's seq00 truth gave -35 steps a minute); the refined rate stays within a bin of the peak."""
    from m3c.eval.plausibility import _fit_frequency

    t = np.arange(150) / 30.0
    rng = np.random.default_rng(0)
    signal = np.where(t < 3.5, 0.3 * np.sin(2 * np.pi * 0.6 * t), 0.0) + 0.02 * rng.standard_normal(150)
    for guess in (0.11, 0.4, 0.79):
        f = _fit_frequency(signal, t, guess, min(0.2, 0.5 * guess))
        assert guess - min(0.2, 0.5 * guess) - 1e-9 <= f <= guess + min(0.2, 0.5 * guess) + 1e-9


def test_a_step_rate_with_a_step_too_short_to_classify_is_timed_as_a_walk_not_confident():
    """The bundled walker after the limb fix: his feet swap at 50 steps a minute (truly 2.085x slow motion) but at
    an uncertain camera scale his steps read 0.56 leg lengths, neither a walk's nor a run's. The rate is still a
    walk's timed (possible slow motion, 110 / 50), never confident; a stroll's length at a normal rate says 1x."""
    from m3c.motion.time_scale import IMAGE_CADENCE, UNCLASSIFIED_GAIT

    short = {"step_rate_spm": 50.0, "step_length_legs": 0.56, "image_step_rate_spm": None}
    estimate = estimate_time_scale([short])
    assert estimate["tracks"][0]["gait"] == UNCLASSIFIED_GAIT
    assert estimate["factor"] == pytest.approx(IMAGE_CADENCE[0] / 50.0, rel=1e-12)
    assert estimate["possible"] and not estimate["confident"]
    assert abs(estimate["factor"] / 2.085 - 1) < 0.1
    normal = estimate_time_scale([{"step_rate_spm": 105.0, "step_length_legs": 0.5}])
    assert not normal["possible"] and normal["factor"] == pytest.approx(110 / 105, rel=1e-12)
