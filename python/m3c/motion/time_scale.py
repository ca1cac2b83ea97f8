"""The video's time scale from the people's gait: how many times slower than it was filmed a video plays.

A step's length does not depend on the playback rate (speed and step rate slow down together), its rate does.
People walk at 100-125 steps a minute whatever their step (0.6-1.05 leg lengths) and run at 140-190 (steps over
1.2 leg lengths): motion capture (Bandai Namco, 5 + 5 clips) walks at 107-118 and runs at 127-162. A track's gait
(m3c.eval.plausibility.gait_figures: steps a minute in the video's time, step length in leg lengths) so measures
the slow-motion factor, expected rate / measured rate, with the spread of human cadence as its uncertainty
(log-sigma WALK_CADENCE[1] or RUN_CADENCE[1]). Steps shorter than 0.4 leg lengths (a shuffle: a slow cadence of
its own) and between the walking and running ranges tell nothing; steps of 0.4-0.6 (a stroll, or a walk read short
at a wrong camera scale) are timed as a walk, never confidently. The people of one video share its
time scale: their factors are fused by a random-effects mean (m3c.vo.scale.between_source_variance), the spread of
one person's cadence not shrinking with the number of frames.

The estimate is reported (results.json video.time_scale, `m3c info`), not applied: the frames node fixes the
frame times before anyone is tracked, and every later node (the motion prior's rate, smoothness, speeds) depends on
them, so `--slow-motion FACTOR` reruns with real time. `possible`: the factor is at least MIN_FACTOR and over
CONFIDENT_SIGMAS of its uncertainty above 1; `confident`: possible, with at least one track's world gait that is
a walk or a run by its step length (the image gait alone misreads a walk that stops for a slow stride: the hard
suite's still camera at normal speed; a step too short for either rests on an uncertain camera scale).
"""

from __future__ import annotations

import numpy as np

from m3c.vo.scale import between_source_variance

# (steps a minute, log-sigma) of people's real cadence: walking and running; and of a gait timed from the image
# alone (no step length to tell a walk from a run: a walk is assumed, and a run, 1.5x faster, lies 2.7 sigma off).
WALK_CADENCE = (110.0, 0.1)
RUN_CADENCE = (165.0, 0.12)
IMAGE_CADENCE = (110.0, 0.15)
IMAGE_GAIT = "stepping (image)"
UNCLASSIFIED_GAIT = "stepping (step length unclassified)"
# Step lengths (leg lengths) that classify a gait: walking within WALK_STEP_LEGS, running over RUN_STEP_LEGS.
WALK_STEP_LEGS = (0.6, 1.05)
RUN_STEP_LEGS = 1.2
# Shorter steps are a shuffle, with a slow cadence of its own: they time nothing. Between this and a walk's, a step
# may be a walk read short at a wrong camera scale: timed, not confidently.
SHUFFLE_STEP_LEGS = 0.4
MIN_FACTOR = 1.3
CONFIDENT_SIGMAS = 3.0


def gait_time_scale(figures: dict) -> tuple[float, float, str] | None:
    """(factor, log-sigma, gait) of one track's gait figures (step_rate_spm in the video's time, step_length_legs):
    the expected real cadence over the measured one; None where the track has no gait or its step is neither a
    walk's nor a run's. A track without a world gait (its fitted feet too rough, or its world too small to travel)
    falls back on its 2D ankles' step rate (image_step_rate_spm) against IMAGE_CADENCE."""
    rate, legs = figures.get("step_rate_spm"), figures.get("step_length_legs")
    if rate is None or legs is None or not (np.isfinite(rate) and rate > 0 and np.isfinite(legs)):
        image = figures.get("image_step_rate_spm")
        if image is None or not (np.isfinite(image) and image > 0):
            return None
        return IMAGE_CADENCE[0] / float(image), IMAGE_CADENCE[1], IMAGE_GAIT
    if WALK_STEP_LEGS[0] <= legs <= WALK_STEP_LEGS[1]:
        (cadence, sigma), gait = WALK_CADENCE, "walking"
    elif legs > RUN_STEP_LEGS:
        (cadence, sigma), gait = RUN_CADENCE, "running"
    elif SHUFFLE_STEP_LEGS <= legs < WALK_STEP_LEGS[0]:
        # A step rate without a step length that tells a walk from a run: timed as the image gait is (a walk
        # assumed, never confident). The length rests on the camera scale, the rate does not: the bundled walker's
        # steps read 0.56 leg lengths at an uncertain scale while his feet swap at 50 steps a minute.
        return IMAGE_CADENCE[0] / float(rate), IMAGE_CADENCE[1], UNCLASSIFIED_GAIT
    else:
        return None
    return cadence / float(rate), sigma, gait


def estimate_time_scale(track_figures: list[dict | None], applied: float = 1.0) -> dict:
    """The slow-motion factor of a video from its tracks' plausibility figures (module docstring), relative to the
    `applied` one (the frames node's slow_motion: the figures are then in its real time). Returns factor (the total
    slow motion the people say: applied x measured; 1.0 with `reason` when nothing measured it), log_sigma, measured
    (the factor beyond the applied one), confident, tracks (per measured track: index, gait, factor) and reason."""
    if not (np.isfinite(applied) and applied > 0):
        raise ValueError(f"applied slow motion must be a number > 0, got {applied!r}")
    per_track = []
    for index, figures in enumerate(track_figures):
        measured = gait_time_scale(figures) if figures else None
        if measured is not None:
            per_track.append({"track": index, "gait": measured[2], "factor": measured[0],
                              "log_sigma": measured[1]})
    if not per_track:
        return {"factor": float(applied), "log_sigma": None, "measured": 1.0, "confident": False,
                "possible": False, "tracks": [], "reason": "no track walks or runs steadily enough to time its steps"}
    logs = np.log([t["factor"] for t in per_track])
    sigmas = np.array([t["log_sigma"] for t in per_track])
    variances = sigmas ** 2 + between_source_variance(logs, sigmas)
    weights = 1.0 / variances
    mean = float(np.sum(weights * logs) / np.sum(weights))
    sigma = float(np.sqrt(1.0 / np.sum(weights)))
    measured = float(np.exp(mean))
    possible = bool(measured >= MIN_FACTOR and mean > CONFIDENT_SIGMAS * sigma)
    image_only = all(t["gait"] in (IMAGE_GAIT, UNCLASSIFIED_GAIT) for t in per_track)
    confident = possible and not image_only
    if confident:
        reason = (f"the people step {measured:.2f}x slower than people walk or run: the video plays slower "
                  "than it was filmed")
    elif possible:
        how = ("timed from the image alone" if all(t["gait"] == IMAGE_GAIT for t in per_track) else
               "their step too short at this camera scale to tell a walk from a run")
        reason = (f"the people step {measured:.2f}x slower than people walk ({how}, a walk assumed: not "
                  "confident)")
    elif mean < -CONFIDENT_SIGMAS * sigma:
        reason = (f"the people step {1 / measured:.2f}x faster than people walk or run (sped up, or a wrong "
                  "gait)")
    else:
        reason = "the people step at a normal rate"
    return {"factor": float(applied * measured), "log_sigma": sigma, "measured": measured,
            "confident": confident, "possible": possible, "tracks": per_track, "reason": reason}
