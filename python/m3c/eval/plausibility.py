"""Plausibility of a world-frame motion where there is no ground truth: figures a person can check against what
people do (a walker moves at 1-1.5 m/s, a planted foot stands still, nobody walks through the floor).

Per track, from its world joints (SMPL 24, metres), the frame rate and its ground plane (n . x + d = 0, the normal
pointing up; y = 0 when none is given):
  mean_speed_mps, peak_speed_mps   horizontal pelvis speed after a 0.5 s smoothing (the gait's sway out)
  sustained_speed_mps              the fastest 1 s average of that speed; implausible_speed: over
                                   MAX_HUMAN_SPEED_MPS (12 m/s, faster than any sprinter holds for a second):
                                   the camera scale or the frame rate is wrong
  path_length_m, displacement_m    the smoothed pelvis path and the straight line from its start to its end
  path_ratio                       path length / displacement (1 for a straight walk; large for a wandering pelvis)
  slow_foot_speed_mps              median over frames of the slower foot's speed (a foot: the slower of its ankle
                                   and foot joints). Retargeted CMU motion capture walking at 1.3 m/s scores 0.13,
                                   standing and jumping 0.07: joint noise and the roll from heel to toe
                                   keep it above zero; sliding feet score several tenths
  below_ground_fraction            share of frames whose lowest foot joint is more than 2 cm below the ground
  penetration_m                    the deepest any foot joint goes below the ground (0 if never)
  step_rate_spm, step_length_m,    the gait (see gait_figures): steps a minute, metres per step (mean speed /
  step_length_legs                 step rate) and that step in leg lengths; None where the feet do not
                                   alternate steadily. Motion capture (Bandai Namco's walks and runs, 5 + 5
                                   clips): walking 107-118 steps a minute at 0.77-0.98 leg lengths a step,
                                   running 127-162 at 0.89-1.83. A normal step at half that rate says the video
                                   plays slower than it was filmed (slow motion), or the speed is wrong
  lead_changes, longest_lead_s     the legs (see leg_figures): how often the leading foot changes and the longest
                                   a foot keeps the lead; a walker's feet swap every step (about 0.5 s), a
                                   foot that leads for seconds while the person walks says the legs never swap
  knee_flex_deg,                   per leg (left, right): the median knee flexion and the share of frames bent
  knee_bent_fraction               over KNEE_BENT_DEG (45): a walk bends a knee past it only in swing, a
                                   fifth of the time or less (CMU walks: 0.07-0.19); a knee bent most of the
                                   time while the other stays straight is a fit gone wrong
  surge_ratio                      sustained_speed_mps / mean_speed_mps: 1 for a steady walk; over 2, the
                                   person advances in surges (both feet planted, then sliding together)
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

PELVIS = (1, 2)              # the hips
FEET = ((7, 10), (8, 11))    # (ankle, foot) joints of the left and right foot
SMOOTHING_S = 0.5
MAX_HUMAN_SPEED_MPS = 12.0
SUSTAINED_S = 1.0
BELOW_GROUND_TOLERANCE = 0.02
LEGS = ((1, 4, 7), (2, 5, 8))  # (hip, knee, ankle) of the left and right leg
# The gait's stride frequencies searched (Hz; 12-240 steps a minute: a walk in 8x slow motion to a sprint), and
# when a track counts as stepping: the
# peak holds at least GAIT_MIN_SHARE of the band's power, the feet's fore-aft alternation is at least
# GAIT_MIN_AMPLITUDE_M, and at least two strides fit in the track.
GAIT_BAND_HZ = (0.1, 2.0)
GAIT_MIN_SHARE = 0.5
GAIT_MIN_AMPLITUDE_M = 0.1
# ... and the track gets somewhere: its pelvis ends at least this far (m/s over its duration) from where it began.
# A standing person's fitted feet can swing rhythmically in depth while his pelvis jitters (the basketball clip's
# standing man: a 0.26 m/s "speed" from jitter, 0.06 m/s of travel).
GAIT_MIN_TRAVEL_MPS = 0.2
# A foot takes the lead when it is LEAD_HYSTERESIS_M ahead of the other (an ankle's noise does not swap it), and a
# knee counts as bent over KNEE_BENT_DEG of flexion.
LEAD_HYSTERESIS_M = 0.05
KNEE_BENT_DEG = 45.0
# Heights are measured to the joints, not the soles: a planted ankle joint sits about 7 cm and a foot joint about
# 2.5 cm above the ground (the open body model at rest: 0.069-0.076 and 0.023-0.030 m over betas -2..2).
FOOT_JOINT_HEIGHT = {7: 0.07, 8: 0.07, 10: 0.025, 11: 0.025}


def _heights(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Signed distance above the plane of points (n, K, 3) with per-frame planes normal (n, 3), offset (n,)."""
    unit = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    scale = np.linalg.norm(normal, axis=-1)
    return np.einsum("nkd,nd->nk", points, unit) + (offset / scale)[:, None]


def _fit_frequency(signal: np.ndarray, t: np.ndarray, guess: float, half_width: float) -> float:
    """The frequency near `guess` (within +- half_width) of the sinusoid plus line that fits `signal` best in the
    least-squares sense: a periodogram's peak is biased when only two or three cycles are in view, this fit is not
    (exact for a pure tone)."""
    candidates = guess + np.linspace(-half_width, half_width, 81)
    residual = []
    for f in candidates:
        basis = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t), t], axis=1)
        coef, *_ = np.linalg.lstsq(basis, signal, rcond=None)
        residual.append(float(np.sum((basis @ coef - signal) ** 2)))
    i = int(np.clip(np.argmin(residual), 1, len(candidates) - 2))
    a, b, c = residual[i - 1:i + 2]
    shift = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c > 0 else 0.0
    shift = float(np.clip(shift, -1.0, 1.0))  # a flat parabola's vertex lies anywhere: within one candidate
    return float(candidates[i] + shift * (candidates[1] - candidates[0]))


def _stride_frequency(signal: np.ndarray, fps: float) -> float | None:
    """The stride frequency (Hz) of a detrended alternation signal over consecutive frames (gait_figures): the
    spectrum's peak within GAIT_BAND_HZ, not at its edges, its main lobe holding GAIT_MIN_SHARE of the band's
    power, refined by _fit_frequency, with two strides in view; None otherwise."""
    n = len(signal)
    t = np.arange(n) / fps
    size = max(8 * n, 4096)
    power = np.abs(np.fft.rfft(signal * np.hanning(n), size)) ** 2
    freq = np.fft.rfftfreq(size, 1.0 / fps)
    band = np.flatnonzero((freq >= GAIT_BAND_HZ[0]) & (freq <= GAIT_BAND_HZ[1]))
    if len(band) < 3:
        return None
    peak = band[np.argmax(power[band])]
    if peak in (band[0], band[-1]):  # rising towards an edge: drift or a rate outside the band, not a gait
        return None
    lobe = np.abs(freq[band] - freq[peak]) <= 2.0 * fps / n
    if power[band][lobe].sum() < GAIT_MIN_SHARE * power[band].sum():
        return None
    # The fit searches +- one bin of the unpadded spectrum, at most half the peak's frequency (never through 0).
    stride = _fit_frequency(signal, t, freq[peak], min(fps / n, 0.5 * freq[peak]))
    inside = GAIT_BAND_HZ[0] <= stride <= GAIT_BAND_HZ[1]
    return stride if inside and n / fps >= 2.0 / stride else None


# The image gait: COCO ankles, the keypoint confidence they need, and the least swing of their difference (in the
# person's image heights) that counts as stepping.
ANKLES_2D = (15, 16)
IMAGE_MIN_CONFIDENCE = 0.3
IMAGE_MIN_AMPLITUDE = 0.03


def image_step_rate(keypoints: np.ndarray, fps: float) -> float | None:
    """Steps a minute from a track's 2D keypoints (n, 17, 3: u, v, confidence) over consecutive frames, or None:
    the two ankles' image offset, in the person's image heights, along its main axis (the rows for a walk towards
    or away from the camera, the columns across it) alternates once per stride (_stride_frequency). It needs
    neither the camera's scale nor its motion nor the optimizer, only the detections; frames without both ankles
    are interpolated, and under half the frames having them gives None."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    n = len(keypoints)
    if keypoints.ndim != 3 or keypoints.shape[1:] != (17, 3):
        raise ValueError(f"keypoints must have shape (n, 17, 3), got {keypoints.shape}")
    ankles = keypoints[:, list(ANKLES_2D)]
    confident = np.nan_to_num(keypoints[..., 2]) >= IMAGE_MIN_CONFIDENCE
    seen = np.isfinite(keypoints[..., :2]).all(axis=-1) & confident
    both = seen[:, ANKLES_2D[0]] & seen[:, ANKLES_2D[1]] & (seen.sum(axis=1) >= 5)
    if n < 8 or both.mean() < 0.5:
        return None
    rows = np.where(seen, keypoints[..., 1], np.nan)
    height = np.nanmax(rows[both], axis=1) - np.nanmin(rows[both], axis=1)
    if not np.all(height > 0):
        return None
    offset = (ankles[both, 0, :2] - ankles[both, 1, :2]) / height[:, None]
    frames = np.flatnonzero(both)
    offset = np.stack([np.interp(np.arange(n), frames, offset[:, c]) for c in range(2)], axis=1)
    offset -= offset.mean(axis=0)
    signal = offset @ np.linalg.svd(offset, full_matrices=False)[2][0]
    t = np.arange(n) / fps
    signal = signal - np.polyval(np.polyfit(t, signal, 1), t)
    if np.sqrt(2.0) * signal.std() < IMAGE_MIN_AMPLITUDE:
        return None
    stride = _stride_frequency(signal, fps)
    return None if stride is None else float(120.0 * stride)


def _lead(joints: np.ndarray, up: np.ndarray) -> np.ndarray | None:
    """(n,) the left ankle's lead over the right (m) along the direction the hips face ((left hip - right hip) x
    up), or None where that direction is undefined."""
    forward = np.cross(joints[:, 1] - joints[:, 2], up)
    norm = np.linalg.norm(forward, axis=1)
    if not np.all(norm > 1e-9):
        return None
    return ((joints[:, 7] - joints[:, 8]) * (forward / norm[:, None])).sum(axis=1)


def leg_figures(joints: np.ndarray, fps: float, up: np.ndarray) -> dict:
    """How the legs move: joints (n, 24, 3) metres over consecutive frames, up (n, 3) unit ground normals.

    lead_changes counts the swaps of the leading foot (_lead beyond +-LEAD_HYSTERESIS_M, a Schmitt trigger),
    longest_lead_s the longest a foot kept the lead (the whole track when it never swapped; None when no foot ever
    led); knee_flex_deg (left, right) the median flexion of each knee (the angle between thigh and shin, 0 for a
    straight leg) and knee_bent_fraction the share of frames it is over KNEE_BENT_DEG."""
    flex = []
    for hip, knee, ankle in LEGS:
        thigh, shin = joints[:, knee] - joints[:, hip], joints[:, ankle] - joints[:, knee]
        cosine = (thigh * shin).sum(-1) / np.maximum(np.linalg.norm(thigh, axis=-1) * np.linalg.norm(shin, axis=-1),
                                                     1e-12)
        flex.append(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
    figures = {"knee_flex_deg": [float(np.median(f)) for f in flex],
               "knee_bent_fraction": [float((f > KNEE_BENT_DEG).mean()) for f in flex],
               "lead_changes": None, "longest_lead_s": None}
    lead = _lead(joints, up)
    if lead is None:
        return figures
    state, since, changes, longest = 0, 0, 0, 0
    for i, value in enumerate(lead):
        now = 1 if value > LEAD_HYSTERESIS_M else -1 if value < -LEAD_HYSTERESIS_M else state
        if now != state:
            if state != 0:
                changes += 1
                longest = max(longest, i - since)
            state, since = now, i
    if state != 0:
        longest = max(longest, len(lead) - since)
        figures.update(lead_changes=changes, longest_lead_s=float(longest / fps))
    return figures


def gait_figures(joints: np.ndarray, fps: float, up: np.ndarray, mean_speed: float) -> dict:
    """Step rate and length of a walking or running track: joints (n, 24, 3) metres over consecutive frames, up
    (n, 3) unit ground normals, mean_speed its mean horizontal speed (m/s).

    A gait alternates the feet: the left ankle's lead over the right along the direction the hips face ((left hip
    - right hip) x up) swings once per stride, two steps. The stride frequency is the peak of that lead's power
    spectrum (linear trend removed, Hann window, zero-padded 8x) within GAIT_BAND_HZ, refined by the least-squares
    fit of a sinusoid (_fit_frequency). It counts only where the peak's main lobe (+- 2 / duration) holds at least
    GAIT_MIN_SHARE of the band's power, the lead swings by at least GAIT_MIN_AMPLITUDE_M (sqrt(2) x its standard
    deviation), the track spans two strides and its pelvis travels at least GAIT_MIN_TRAVEL_MPS from start to end;
    otherwise every figure is None. The step length is mean_speed over the step rate, also in leg lengths
    (hip-knee-ankle, the median over frames and legs)."""
    none = {"step_rate_spm": None, "step_length_m": None, "step_length_legs": None}
    n = len(joints)
    if n < 8:
        return none
    t = np.arange(n) / fps
    travel = joints[-1, list(PELVIS)].mean(axis=0) - joints[0, list(PELVIS)].mean(axis=0)
    travel -= (travel @ up[-1]) * up[-1]
    if np.linalg.norm(travel) < GAIT_MIN_TRAVEL_MPS * t[-1]:
        return none
    stride = stride_frequency(joints, fps, up)
    if stride is None:
        return none
    step = mean_speed / (2.0 * stride)
    return {"step_rate_spm": float(120.0 * stride), "step_length_m": float(step),
            "step_length_legs": float(step / leg_length(joints))}


def stride_frequency(joints: np.ndarray, fps: float, up: np.ndarray) -> float | None:
    """The stride frequency (Hz) of the feet's alternation (gait_figures' rule, without its travel check), or None
    where they do not alternate steadily. It reads only each frame's own joints (the lead of one ankle over the
    other), so it holds in any frame whose rotation is right, whatever its translation or scale."""
    lead = _lead(joints, up) if len(joints) >= 8 else None
    if lead is None:
        return None
    t = np.arange(len(joints)) / fps
    lead = lead - np.polyval(np.polyfit(t, lead, 1), t)
    if np.sqrt(2.0) * lead.std() < GAIT_MIN_AMPLITUDE_M:
        return None
    return _stride_frequency(lead, fps)


def leg_length(joints: np.ndarray) -> float:
    """Hip-knee-ankle length (m), the median over frames and legs."""
    return float(np.median([np.linalg.norm(joints[:, hip] - joints[:, knee], axis=1) +
                            np.linalg.norm(joints[:, knee] - joints[:, ankle], axis=1) for hip, knee, ankle in LEGS]))


def track_plausibility(joints: np.ndarray, fps: float, ground_normal=None, ground_offset=None) -> dict:
    """Figures of one track: joints (n, 24, 3) world over consecutive frames; ground planes (n, 3) and (n,) or
    None for y = 0."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1] < 12 or joints.shape[2] != 3:
        raise ValueError(f"joints must have shape (n, 24, 3), got {joints.shape}")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    n = len(joints)
    if n < 2 or not np.all(np.isfinite(joints)):
        raise ValueError("plausibility needs at least 2 frames of finite joints")
    if ground_normal is None:
        ground_normal, ground_offset = np.tile([0.0, 1.0, 0.0], (n, 1)), np.zeros(n)
    normal = np.asarray(ground_normal, dtype=np.float64).reshape(n, 3)
    offset = np.asarray(ground_offset, dtype=np.float64).reshape(n)
    # Horizontal motion: components along the ground.
    unit = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    # A quadratic Savitzky-Golay smoothing over 0.5 s: removes the gait's sway, keeps steady motion exact up to
    # the ends (a moving average would slow the first and last quarter second).
    pelvis = joints[:, list(PELVIS)].mean(axis=1)
    window = min(n, round(SMOOTHING_S * fps)) // 2 * 2 + 1
    if window > n:
        window -= 2
    if window >= 3:
        pelvis = savgol_filter(pelvis, window, polyorder=min(2, window - 1), axis=0, mode="interp")
    step = np.diff(pelvis, axis=0)
    step -= (step * unit[1:]).sum(-1, keepdims=True) * unit[1:]
    speed = np.linalg.norm(step, axis=-1) * fps
    width = max(1, round(SUSTAINED_S * fps))
    sustained = float(np.convolve(speed, np.full(width, 1.0 / width), "valid").max()) if len(speed) >= width \
        else float(speed.mean())
    path = float(np.linalg.norm(step, axis=-1).sum())
    line = pelvis[-1] - pelvis[0]
    line -= (line @ unit[-1]) * unit[-1]
    displacement = float(np.linalg.norm(line))
    # A planted foot has its heel (ankle joint) or its toes (foot joint) still: each foot moves at the slower of
    # its two joints, and the slower foot is the one that may be planted.
    joint_speed = np.linalg.norm(np.diff(joints, axis=0), axis=-1) * fps  # (n - 1, 24)
    slow_foot = np.min([joint_speed[:, list(pair)].min(axis=1) for pair in FEET], axis=0)
    ids = [j for pair in FEET for j in pair]
    heights = _heights(joints[:, ids], normal, offset) - np.array([FOOT_JOINT_HEIGHT[j] for j in ids])
    lowest = heights.min(axis=1)
    return {
        "frames": int(n),
        "mean_speed_mps": float(speed.mean()),
        "peak_speed_mps": float(speed.max()),
        "sustained_speed_mps": sustained,
        "implausible_speed": bool(sustained > MAX_HUMAN_SPEED_MPS),
        "path_length_m": path,
        "displacement_m": displacement,
        "path_ratio": float(path / displacement) if displacement > 1e-3 else None,
        "slow_foot_speed_mps": float(np.median(slow_foot)),
        "below_ground_fraction": float((lowest < -BELOW_GROUND_TOLERANCE).mean()),
        "penetration_m": float(max(0.0, -lowest.min())),
        "surge_ratio": float(sustained / speed.mean()) if speed.mean() > 1e-6 else None,
        **gait_figures(joints, fps, unit, float(speed.mean())),
        **leg_figures(joints, fps, unit),
    }


def results_plausibility(arrays: dict) -> list[dict | None]:
    """Per track of a results.npz dict: the figures over its longest run of consecutive valid frames (None for a
    track shorter than 2 frames), with the track's per-frame ground planes where it has them, and the step rate of
    its 2D ankles (image_step_rate_spm, image_step_rate) where the arrays hold keypoints_2d."""
    fps = float(arrays["fps"])
    out = []
    for p in range(len(arrays["track_ids"])):
        valid = np.asarray(arrays["valid"][p], bool) & np.isfinite(arrays["world_joints"][p]).all(axis=(1, 2))
        frames = np.flatnonzero(valid)
        if len(frames) < 2:
            out.append(None)
            continue
        breaks = np.flatnonzero(np.diff(frames) != 1) + 1
        runs = np.split(frames, breaks)
        run = max(runs, key=len)
        if len(run) < 2:
            out.append(None)
            continue
        normal, offset = arrays["ground_normal"][p, run], arrays["ground_offset"][p, run]
        planes = np.isfinite(normal).all() and np.isfinite(offset).all()
        figures = track_plausibility(arrays["world_joints"][p, run], fps, normal if planes else None,
                                     offset if planes else None)
        if "keypoints_2d" in arrays:
            figures["image_step_rate_spm"] = image_step_rate(arrays["keypoints_2d"][p, run], fps)
        out.append(figures)
    return out
