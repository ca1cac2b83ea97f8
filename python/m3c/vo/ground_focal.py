"""The focal length of a still camera from where the people stand: their planted feet and the scene's vertical
vanishing point.

A still camera's motion says nothing about its focal length (m3c.vo.focal), and the scene's lines give it only
where a built scene shows two perpendicular directions (m3c.vo.vanishing). People walking over a flat ground
give it when the camera looks down or up, with the vertical vanishing point alone:

A ground point P at depth Z seen at the centred pixel (u, v) is P = (Z / f) (u, v, f). The ground is the plane
up . P = c whose normal is the up direction, and the up direction is the vertical vanishing point's ray:
up ~ (a, b, f w) for the vanishing point's homogeneous centred pixel (a, b, w). So (Z / f) (a u + b v + f^2 w) = c,
that is, with q = f / Z (a body's pixels per metre at that depth, which a body fitted at any focal length keeps:
its depth scales with the focal length it was fitted at) and g = a u + b v (the foot's pixel along the vanishing
point's direction):

    q = g / c + f^2 w / c,        a line in g whose intercept over its slope is f^2 w.

A person's planted feet over time sample that line wherever they walk nearer or further; where q = 0 is the
horizon. Per person a robust line fit (Huber) of q on g over its planted ankles gives f^2 (its own c absorbs the
person's size error and the ankles' height above the ground); a block bootstrap over time its uncertainty; the
people's estimates are pooled by inverse variance and, where informative, fused with the caller's default as a
prior. A level camera (w -> 0) or a person who keeps one distance (no spread of q: a tracking shot) leaves f
unobservable, which the bootstrap's spread says.

    estimate = focal_from_planted_feet(people, vertical, default)   # people: [(pixels (n, 2), q (n,), time (n,))]
    estimate.focal, estimate.log_sigma, estimate.informative
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from m3c.vo.odometry import check_settings
from m3c.vo.vanishing import MAX_UP_SPREAD, agreeing_direction


@dataclass
class GroundFocalConfig:
    """Settings of focal_from_planted_feet.

    contact_threshold: an ankle's planted probability above which it is a ground point; min_points: the
    planted points a person needs; block_frames: the bootstrap resamples blocks of this many frames (a planted
    foot's frames are not independent); resamples: bootstrap draws; max_log_sigma: the pooled estimate is
    informative when its uncertainty in log(focal) is within this (0.2: of the 13 still cameras measured, the video
    benchmark's and the calibrated lab's with its lines off, the two at 0.16 were within 2.4% of the truth, the two
    above 0.2 (0.30, 0.38) 80% off or unobservable); bias_log_sigma: the estimator's own error beyond
    the bootstrap's, added to it in quadrature before the fusion (the people's monocular depths err more the
    further they stand, which tilts the line: 1-20% on the video benchmark's static cameras); prior_log_sigma: the
    spread of real cameras' focal lengths around the default (log), the prior the measurement is fused with;
    min_camera_tilt: degrees the
    camera must look up or down at the default focal (a level camera's ground gives no focal length); low, high:
    the focal lengths the pooled estimate may take (x the default), else not informative; seed: the bootstrap."""

    contact_threshold: float = 0.5
    min_points: int = 30
    block_frames: int = 15
    resamples: int = 200
    max_log_sigma: float = 0.2
    bias_log_sigma: float = 0.1
    prior_log_sigma: float = 0.3
    min_camera_tilt: float = 2.0
    low: float = 0.4
    high: float = 2.5
    seed: int = 0

    def fusion_weights(self, log_sigma: float) -> tuple[float, float]:
        """(the default's, the measurement's) inverse variances in log(focal) when a measurement of log-sigma
        `log_sigma` is fused with the default; 1 / sqrt(their sum) is the fused focal length's log-sigma."""
        return 1.0 / self.prior_log_sigma ** 2, 1.0 / (log_sigma ** 2 + self.bias_log_sigma ** 2)

    def __post_init__(self):
        check_settings(self, {"min_points": 3, "block_frames": 1, "resamples": 10, "seed": 0},
                       ("contact_threshold", "max_log_sigma", "bias_log_sigma", "prior_log_sigma", "min_camera_tilt",
                        "low", "high"), strictly_positive=True, what="ground focal: ")
        if not self.low < 1.0 < self.high:
            raise ValueError(f"ground focal: low ({self.low}) and high ({self.high}) must enclose 1 (the default)")


@dataclass
class GroundFocal:
    """focal: pixels (the default where not informative); measured: the people's pooled focal before the prior
    (None without one); log_sigma: the pooled measurement's uncertainty in log(focal) (inf without one);
    informative; people: per person its focal (None where its line gave no positive f^2), log_sigma and points;
    message: why."""

    focal: float
    default: float
    measured: float | None = None
    log_sigma: float = math.inf
    informative: bool = False
    people: list[dict] = field(default_factory=list)
    message: str = ""

    def summary(self) -> dict:
        return {"focal": float(self.focal), "default": float(self.default), "measured": self.measured,
                "log_sigma": self.log_sigma if math.isfinite(self.log_sigma) else None,
                "informative": bool(self.informative), "people": self.people, "message": self.message}


# The contact joints (m3c.body.joint_names.CONTACT_JOINTS' order) whose planted positions sample the ground: the two
# ankles, one height above it. The toe joints sit a few centimetres lower and 15 cm further: mixed with the ankles
# they would draw a line within one standing body.
GROUND_CONTACTS = (0, 1)


def planted_points(model, tracks, focal: float, threshold: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per perception track (m3c.perception.handover: frame, pose, betas, transl at `focal`, contacts) its planted
    ankles as (centred pixels (n, 2), q = focal / depth (n,), frames (n,)); a track without camera-local
    translations (crop_cam only) gives none."""
    from m3c.body.joint_names import CONTACT_JOINTS

    joint_ids = [CONTACT_JOINTS[k] for k in GROUND_CONTACTS]
    out = []
    for track in tracks:
        if "transl" not in track or "contacts" not in track:
            continue
        joints = model.joints(track["pose"], track["betas"], track["transl"])[:, joint_ids]
        contacts = np.asarray(track["contacts"])[:, list(GROUND_CONTACTS)]
        planted = (contacts > threshold) & (joints[..., 2] > 1e-6)
        points = joints[planted]
        frames = np.broadcast_to(np.asarray(track["frame"])[:, None], planted.shape)[planted]
        out.append((focal * points[:, :2] / points[:, 2:], focal / points[:, 2], frames))
    return out


def scene_vertical(scene, focal: float, max_spread: float = MAX_UP_SPREAD) -> tuple[np.ndarray | None, str]:
    """(the vertical vanishing point (a, b, w) in homogeneous centred pixels, "") of a still camera's scene
    (m3c.vo.vanishing.SceneCamera), or (None, why) where fewer than two sampled frames found one or their up
    directions (at `focal`) scatter more than max_spread degrees (RMS): not one camera pose, or not vertical edges."""
    ups = [scene.up(focal, f.frame) for f in scene.frames]
    if len(ups) < 2:
        return None, f"{len(ups)} sampled frames found a vertical vanishing point, 2 needed"
    mean, spread, kept = agreeing_direction(ups, max_spread)
    if mean is None:
        return None, (f"the frames' vertical vanishing points are {spread:.1f} degrees apart (RMS over {kept.sum()} of "
                      f"{len(ups)} frames), over {max_spread:g}")
    return np.array([mean[0], mean[1], mean[2] / focal]), ""


def _huber_line(g: np.ndarray, q: np.ndarray, iterations: int = 15) -> tuple[float, float]:
    """(slope, intercept) of q on g, Huber-weighted (k = 1.5 robust sigmas) by iterated reweighted least squares."""
    weights = np.ones_like(g)
    design = np.stack([g, np.ones_like(g)], axis=1)
    slope, intercept = 0.0, float(np.median(q))
    for _ in range(iterations):
        root = np.sqrt(weights)
        solution, *_ = np.linalg.lstsq(design * root[:, None], q * root, rcond=None)
        slope, intercept = float(solution[0]), float(solution[1])
        residual = np.abs(q - slope * g - intercept)
        k = 1.5 * 1.4826 * float(np.median(residual)) + 1e-12
        weights = np.where(residual <= k, 1.0, k / np.maximum(residual, 1e-300))
    return slope, intercept


def _focal_squared(g: np.ndarray, q: np.ndarray, w: float) -> float:
    slope, intercept = _huber_line(g, q)
    return intercept / (slope * w) if slope * w != 0 else math.nan


def person_focal(pixels, q, time, vertical, config: GroundFocalConfig, rng: np.random.Generator
                 ) -> tuple[float | None, float]:
    """(focal, log_sigma) of one person's planted points: pixels (n, 2) centred, q (n,) pixels per metre at their
    depth, time (n,) their frames; vertical (a, b, w) the vertical vanishing point, homogeneous centred pixels.
    focal None (log_sigma inf) where the line gives no positive f^2 or too few bootstrap draws do."""
    a, b, w = (float(x) for x in vertical)
    g = np.asarray(pixels, dtype=np.float64) @ np.array([a, b])
    q = np.asarray(q, dtype=np.float64)
    if np.ptp(g) == 0:  # every point at one distance: no line
        return None, math.inf
    f2 = _focal_squared(g, q, w)
    if not (math.isfinite(f2) and f2 > 0):
        return None, math.inf
    # Block bootstrap: whole stretches of frames in or out, so the spread sees the feet's correlated errors.
    time = np.asarray(time)
    blocks = [np.flatnonzero(time // config.block_frames == k) for k in np.unique(time // config.block_frames)]
    if len(blocks) < 3:
        return float(math.sqrt(f2)), math.inf
    draws = []
    for _ in range(config.resamples):
        rows = np.concatenate([blocks[i] for i in rng.integers(0, len(blocks), len(blocks))])
        if np.ptp(g[rows]) > 0:
            draws.append(_focal_squared(g[rows], q[rows], w))
    draws = np.array(draws)
    good = np.isfinite(draws) & (draws > 0)
    # The line's intercept swinging through zero: no focal length to speak of.
    if len(draws) < 0.9 * config.resamples or good.mean() < 0.9:
        return float(math.sqrt(f2)), math.inf
    lo, hi = np.percentile(0.5 * np.log(draws[good]), [16, 84])
    return float(math.sqrt(f2)), max(float(0.5 * (hi - lo)), 1e-9)  # exact points: no spread at all


def focal_from_planted_feet(people, vertical, default: float, config: GroundFocalConfig | None = None
                            ) -> GroundFocal:
    """The estimate from people: a list of (pixels (n, 2) centred, q (n,), time (n,)) of each person's planted
    points (see the module's docstring), vertical: the vertical vanishing point (a, b, w) in homogeneous centred
    pixels, default: the focal length (pixels) kept where the people cannot tell, and the prior's centre."""
    config = config or GroundFocalConfig()
    if not (math.isfinite(default) and default > 0):
        raise ValueError(f"the default focal length must be a positive number of pixels, got {default}")
    vertical = np.asarray(vertical, dtype=np.float64)
    if vertical.shape != (3,) or not np.isfinite(vertical).all() or not np.any(vertical[:2]):
        raise ValueError(f"vertical must be a finite homogeneous vanishing point (a, b, w) with (a, b) != 0, "
                         f"got {vertical}")
    out = GroundFocal(default, default)
    tilt = math.degrees(math.atan2(abs(vertical[2]) * default, math.hypot(*vertical[:2])))
    if tilt < config.min_camera_tilt:
        out.message = (f"the camera looks {tilt:.1f} degrees up or down (vertical vanishing point), under "
                       f"{config.min_camera_tilt:g}: a level camera's ground gives no focal length")
        return out
    rng = np.random.default_rng(config.seed)
    estimates = []
    for pixels, q, time in people:
        q = np.asarray(q, dtype=np.float64)
        entry = {"points": int(len(q)), "focal": None, "log_sigma": None}
        if len(q) >= config.min_points:
            focal, sigma = person_focal(pixels, q, time, vertical, config, rng)
            entry["focal"] = focal
            if math.isfinite(sigma):
                entry["log_sigma"] = sigma
                estimates.append((math.log(focal), sigma))
        out.people.append(entry)
    if not estimates:
        out.message = (f"no person's planted feet ({sum(e['points'] for e in out.people)} points over "
                       f"{len(out.people)} people, {config.min_points} each needed) located the horizon")
        return out
    weights = np.array([1.0 / s ** 2 for _, s in estimates])
    log_measured = float(np.sum(weights * [m for m, _ in estimates]) / weights.sum())
    out.measured, out.log_sigma = math.exp(log_measured), float(1.0 / math.sqrt(weights.sum()))
    ratio = out.measured / default
    if out.log_sigma > config.max_log_sigma or not config.low <= ratio <= config.high:
        out.message = (f"the planted feet put the focal length at {out.measured:.0f} px (x{ratio:.2f} the default, "
                       f"log-sigma {out.log_sigma:.2f}): not informative (log-sigma within "
                       f"{config.max_log_sigma:g} and x{config.low:g}..{config.high:g} needed); keeping the default")
        return out
    # Fused with the default as a prior: a measurement as uncertain as real cameras' spread moves half-way.
    prior, measured = config.fusion_weights(out.log_sigma)
    out.focal = float(math.exp((prior * math.log(default) + measured * log_measured) / (prior + measured)))
    out.informative = True
    who = "1 person" if len(estimates) == 1 else f"{len(estimates)} people"
    out.message = (f"the planted feet of {who} put the focal length at {out.measured:.0f} px "
                   f"(log-sigma {out.log_sigma:.2f}); with the default {default:.0f} px as the prior: "
                   f"{out.focal:.0f} px")
    return out
