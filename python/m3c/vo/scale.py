"""The metric size of one visual-odometry translation unit: M3C's one camera scale estimator.

Monocular odometry gives the camera's path up to scale s (metres per VO unit). Every observation that carries
metric size gives a measurement of log s with a standard deviation; the estimate is their inverse-variance
weighted mean in log space (`fuse`), reported with its uncertainty and every observation (results.json).

Observations (each returns a ScaleObservation, or one with a reason when it has nothing to go on):
  planted feet   (`scale_from_planted_feet`) a foot joint planted over a run of frames is one world point:
                 R_t x_t + s c_t is constant (x_t: the joint in camera t, metres, from the camera-local body;
                 R_t, c_t: the VO rotation and camera centre). After centring each run, a_t + s b_t = 0 is solved
                 by weighted least squares in each frame's camera axes, the depth axis down-weighted
                 (DEPTH_WEIGHT): a monocular body's depth comes from its size and is several times noisier
                 than its image-plane position, and a camera moving along its view sees the foot move in depth.
                 Its uncertainty is a bootstrap over the runs (the independent units), plus FEET_MODEL_SIGMA for
                 what no resampling of the runs can see: planted frames that are not.
  ground         (`scale_from_camera_height`) the people's known size puts their contact points (metres) in
                 each camera, and so the camera's metric height above the ground they stand on; the odometry's
                 map points on the ground give the same height in VO units (`map_ground_plane`: the dominant
                 plane below the cameras, its normal near the people's upright direction). Each frame's ratio
                 is a measurement; each person's median of them is one estimate, carrying that person's size
                 error whatever the number of frames, so the people's estimates are averaged with equal weight
                 (in log). The uncertainty: each person's robust spread over the independent frames, or the
                 people's scatter about their mean when that is larger. This cue barely depends on the focal
                 length (a height is an image-plane offset times depth / focal, and the body's depth scales with
                 the focal length).
  gait           (`scale_from_gait`) a walker's step is about GAIT_STEP_LEGS of his leg length, whatever the
                 camera and whatever the video's speed (slow motion changes the cadence, not the step). His
                 pelvis in the world at scale s is s c_t + R_t p_t (p_t in camera t, metres); the straight line
                 fitted to it over the frames moves s A + B a frame, and a step is |s A + B| / (2 f) for a stride
                 frequency f (cycles a frame, from the feet's alternation, which reads each frame's own joints and
                 so needs no scale). Solving |s A + B| = 2 f GAIT_STEP_LEGS leg gives s; its uncertainty is
                 GAIT_STEP_SIGMA times how strongly s follows the step (at least 1: 1 where the person's travel is
                 the camera's; a person walking before a still camera gives no scale and is left out), with
                 GAIT_MODEL_SIGMA for strides read from walks that are not steady.
  depth map      (`scale_from_depth`) metric depth maps (a depth node that says `metric`) against the depths
                 of the map points in each frame.
Only the people near the camera measure the scale (`scale_subjects`, SUBJECT_DEPTH_RATIO): a body far off in a
crowd has contacts and a size too poor to count, and its errors do not average out with the others'. The ground's
map plane must have points where those people stand (`floor_support`, FLOOR_SUPPORT): on a plain or glossy floor
the odometry has none there, and the plane it finds is the background's.
Sources measured from the people's size (feet, ground) share one systematic relative error (PERSON_SIZE_SIGMA, the
spread of adult stature the body's shape estimate cannot see): they are fused by their sampling errors and the
systematic error is added once to their mean, which is then fused with the other sources.

Sources that disagree beyond their uncertainty (the ground under a low-parallax camera, a plane that is not the
floor, contacts that are not) are not settled by trusting the tighter one: the fusion is a random-effects mean
(DerSimonian-Laird). The spread of the sources beyond their own errors, tau^2, where Cochran's test finds one
(HETEROGENEITY_ALPHA), is added to every source's variance, so the mean moves towards an equal-weight mean of the
sources and its uncertainty covers their spread;
when two of them lie more than 3 combined standard deviations apart (`consistent` False) the 2-sigma interval
also reaches every source's value. With three or more sources, one that disagrees with all the others while they
agree among themselves is the wrong one: it is set aside (`reason` says with whom it disagreed) and the rest
fused; two camps that each agree within themselves are not settled that way.

The ground source checks the camera height it implies (metres, from the people): a camera whose scale can be
measured moves, and one carried or held sits 0.3-3 m above the floor (PLAUSIBLE_CAMERA_HEIGHT_M); a height outside
that range says the map's plane or the contacts are wrong by at least that ratio, which joins the source's
uncertainty (`detail["camera_height_suspect"]`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.stats import chi2

from m3c.camera import project, to_camera

# Relative standard deviation of a person's metric size as a monocular body estimate sees it: adult stature
# varies by about 4% around its mean and the shape estimate recovers little of it.
PERSON_SIZE_SIGMA = 0.05
# Weight of the depth axis against the image-plane axes in the planted-feet fit (variance ratio ~ 1:10).
DEPTH_WEIGHT = 0.1
# Quantile of the contact vertices' depth below the camera taken as the soles' (robust to a stray vertex).
SOLE_QUANTILE = 0.9
# Frames per independent measurement of the camera height (people's contacts change over half a second).
FRAMES_PER_SAMPLE = 15
# Relative error of the planted-feet fit that its bootstrap over runs cannot see: the contacts it trusts are decided
# from heights alone in a moving camera (on the video benchmark they agree with the true contacts in about 55% of
# frames). Measured over the benchmark's moving cameras (seeds 0 and 1, the perception of two code versions: 16
# runs): the source's log errors have an RMS of 0.28 (-59% to +32%) and its bootstrap sigmas one of 0.15; the
# variance they leave unexplained is 0.23^2.
FEET_MODEL_SIGMA = 0.23
# Camera heights above the ground (metres) that a moving camera is plausibly carried at: a crouching operator to a
# raised gimbal (the video benchmark's moving cameras: 1.2-3 m). The bundled-clip-like failure it catches: a hall
# with a plain floor whose map "ground" put a chest-height camera 3.6 m up.
PLAUSIBLE_CAMERA_HEIGHT_M = (0.3, 3.0)
# A walking step in leg lengths (hip-knee-ankle) and its log spread: motion capture walks 0.77-0.98 (Bandai Namco,
# 5 clips; m3c.eval.plausibility), runs 0.89-1.83. The spread is a walk's across people and speeds and takes in
# slow jogs at 2 sigma (0.58-1.30); a run taken for a walk reads as a smaller scale (its longer step taken for
# a faster camera).
GAIT_STEP_LEGS = 0.87
GAIT_STEP_SIGMA = 0.2
# The gait source's error beyond the step's spread: a stride read from a fitted body that is not a steady walk (the
# video benchmark's walkers stroll and turn: their true feet rarely alternate steadily). Measured on its readings
# over the default set and the hard suite (seeds 0 and 1): +10%, +41%, +106% and +233% (log RMS 0.72) at sigmas of
# 0.11-0.23; the variance they leave unexplained is about 0.7^2.
GAIT_MODEL_SIGMA = 0.7
# A track whose scale follows its step more weakly than this (d log s / d log step, > 1 where the person's own
# motion in the camera adds to the camera's) says little about the scale; one whose pelvis path at the solved scale
# is over GAIT_MAX_PATH_RATIO its displacement is not walking a straight line, which the step's speed assumes.
GAIT_MAX_SENSITIVITY = 2.0
GAIT_MAX_PATH_RATIO = 1.3
# People farther than this multiple of the nearest person's depth give no scale evidence: a monocular body's contacts
# and size degrade as it shrinks in the image, and its errors do not average out (its planted feet are mostly
# walking feet). Hard suite's crowds (seq10 seeds 0 and 1, planted feet per person, log error): the nearest
# people (3.8-4.1 m) -0.06 and -0.07; at 1.76x the nearest's depth +0.51; at 2.9-5.5x from -0.07 to +3.9, 8 of 10
# above +0.18. The nearest is the nearest person seen for SUBJECT_MIN_FRAMES frames (a passer-by is not the
# reference).
SUBJECT_DEPTH_RATIO = 1.6
SUBJECT_MIN_FRAMES = 30
# A map plane measures the camera's height only where the people stand on it: at least FLOOR_SUPPORT of its points
# within FLOOR_RADIUS camera heights of the subjects' footprints (where their contacts' lines of sight meet it).
# Where the floor gives the odometry no points near the people its dominant "plane" is the background's, at the
# wrong height. Video benchmark, seed 0 (and 1): the textured floors' planes 630-2714 points; the right plane of a
# plain floor (hard seq04) 26; the wrong planes over a plain floor in a crowd and a glossy hall (seq10, seq12,
# ground sources 20-39% off) none, in both seeds.
FLOOR_SUPPORT = 10
FLOOR_RADIUS = 1.5
# The sources' spread beyond their own errors is added (random effects) only where Cochran's Q test finds it at this
# level: with two or three sources, DerSimonian-Laird's tau^2 is positive whenever Q exceeds its mean, which calibrated
# sources do about a third of the time, and it then pulls the mean off a tight source towards a wide one that agrees
# with it (the hard suite's plain-floor handheld camera: a gait 2.3 sigma off dragged the fused scale from +3% to
# +21%).
HETEROGENEITY_ALPHA = 0.05
# The fused scale's confidence (ScaleEstimate.confidence) from its log-sigma: "high" under the first, "medium" under
# the second, else "low"; sources that disagree make it "low" whatever the sigma.
CONFIDENCE_SIGMA = (0.1, 0.25)


@dataclass
class ScaleObservation:
    """One source's measurement: value (metres per VO unit) with sigma, the standard deviation of log(value)
    (a relative error) from sampling, from `frames` frames; person_size: measured against the people's size (it
    also carries PERSON_SIZE_SIGMA, shared by all such sources). value None with `reason` when the source had
    nothing to go on."""
    source: str
    value: float | None = None
    sigma: float | None = None
    frames: int = 0
    reason: str = ""
    detail: dict = field(default_factory=dict)
    person_size: bool = True

    def usable(self) -> bool:
        return self.value is not None and self.sigma is not None and np.isfinite(self.sigma) and self.sigma > 0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class ScaleEstimate:
    """The camera scale (metres per VO unit): value, sigma (standard deviation of log(value)), source (the
    sources used, "+"-joined; "given", "static camera" or "default" when nothing measured it) and every
    observation. consistent: False when two sources disagree by more than 3 combined standard deviations.
    spread: tau, the sources' log spread beyond their own errors that the random-effects fusion added to each
    (0 when they agree). ground_plane: (nx, ny, nz, d) the odometry map's ground (n . x + d = 0, x in the VO frame
    and VO units, map_ground_plane) that the ground source measured the camera's height against; None without one."""
    value: float
    sigma: float | None
    source: str
    observations: list[ScaleObservation] = field(default_factory=list)
    consistent: bool = True
    ground_plane: list | None = None
    spread: float = 0.0

    @property
    def confidence(self) -> str:
        """"high", "medium" or "low" (CONFIDENCE_SIGMA; "low" when the sources disagree); "none" without a sigma
        (nothing measured the scale, or it needs none: given, a static camera)."""
        if self.sigma is None:
            return "none"
        if not self.consistent:
            return "low"
        if self.sigma < CONFIDENCE_SIGMA[0]:
            return "high"
        return "medium" if self.sigma < CONFIDENCE_SIGMA[1] else "low"

    def disagreement(self) -> str:
        """A sentence on sources that disagree beyond their uncertainty ("" when they agree)."""
        if self.consistent:
            return ""
        sources = ", ".join(f"{o.source} {o.value:.4g} (+-{100 * o.sigma:.0f}%)" for o in self.observations
                            if o.usable())
        return (f"the camera scale's sources disagree beyond their uncertainty ({sources}): the fused "
                f"{self.value:.4g} m per VO unit is uncertain by a factor of {np.exp(2 * self.sigma):.2f} either "
                "way (2 sigma), and the world's size with it")

    def to_dict(self) -> dict:
        return {"value": float(self.value), "sigma": None if self.sigma is None else float(self.sigma),
                "source": self.source, "consistent": bool(self.consistent), "spread": float(self.spread),
                "confidence": self.confidence, "disagreement": self.disagreement(),
                "observations": [o.to_dict() for o in self.observations],
                "ground_plane": None if self.ground_plane is None else [float(v) for v in self.ground_plane]}


# A camera that turns in place: its odometry translation is noise, small against the scene and wandering back and
# forth, and any scale would multiply it into metres. Both must hold: its extent (farthest centre from the first) is
# under MIN_BASELINE of the scene's median depth, and its path is over MAX_WANDER times that extent. On the video
# benchmark the panning and static cameras span 0.02-0.06 of the depth with paths 2.0-2.9x their extent; the moving
# ones 0.06-1.5 (the bundled walker's first 2 s: 0.055) with paths 1.0-1.75x.
MIN_BASELINE = 0.1
MAX_WANDER = 1.9


def translation_baseline(world_from_cam: np.ndarray, points: np.ndarray) -> tuple[float, float] | None:
    """(extent / median depth, path / extent) of the camera's odometry translation: extent the farthest centre from
    the first, path the summed steps, depth the median distance from the middle camera to the map points, all in VO
    units; None without map points or translation."""
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centres = world_from_cam[:, :3, 3]
    extent = float(np.linalg.norm(centres - centres[0], axis=1).max())
    if not len(points) or extent <= 0:
        return None
    depth = float(np.median(np.linalg.norm(points - centres[len(centres) // 2], axis=1)))
    path = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
    return (extent / depth if depth > 0 else float("inf")), path / extent


def turns_in_place(world_from_cam: np.ndarray, points: np.ndarray, min_baseline: float = MIN_BASELINE,
                   max_wander: float = MAX_WANDER) -> bool:
    """Whether the odometry's translation is the noise of a camera that turns in place (see MIN_BASELINE)."""
    baseline = translation_baseline(world_from_cam, points)
    return baseline is not None and baseline[0] < min_baseline and baseline[1] > max_wander


def _weighted(logs: np.ndarray, sigmas: np.ndarray) -> tuple[float, float]:
    weights = 1.0 / np.square(np.maximum(sigmas, 1e-6))
    return float(np.sum(weights * logs) / np.sum(weights)), float(np.sqrt(1.0 / np.sum(weights)))


def _grouped(logs: np.ndarray, variances: np.ndarray, person: np.ndarray) -> tuple[float, float]:
    """The people-based sources' weighted mean with PERSON_SIZE_SIGMA added once, fused with the other sources:
    (mean, sigma) of log s."""
    groups_logs, groups_sigmas = list(logs[~person]), list(np.sqrt(variances[~person]))
    if person.any():
        mean, sigma = _weighted(logs[person], np.sqrt(variances[person]))
        groups_logs.append(mean)
        groups_sigmas.append(float(np.hypot(sigma, PERSON_SIZE_SIGMA)))
    return _weighted(np.array(groups_logs), np.array(groups_sigmas))


def between_source_variance(logs: np.ndarray, sigmas: np.ndarray, alpha: float | None = None) -> float:
    """tau^2, the DerSimonian-Laird estimate of the sources' variance beyond their own errors: (Q - (k - 1)) /
    (sum w - sum w^2 / sum w), Q the chi^2 of the logs about their inverse-variance mean (w = 1 / sigma^2); 0 when
    Q does not exceed its expectation k - 1, or, given alpha, when Cochran's test does not find the spread at that
    level (Q under the chi^2 quantile 1 - alpha with k - 1 degrees of freedom)."""
    logs, sigmas = np.asarray(logs, dtype=np.float64), np.asarray(sigmas, dtype=np.float64)
    if len(logs) < 2:
        return 0.0
    weights = 1.0 / np.square(np.maximum(sigmas, 1e-6))
    mean = np.sum(weights * logs) / np.sum(weights)
    q = float(np.sum(weights * (logs - mean) ** 2))
    if alpha is not None and q <= chi2.ppf(1.0 - alpha, len(logs) - 1):
        return 0.0
    denominator = float(np.sum(weights) - np.sum(weights ** 2) / np.sum(weights))
    return max(0.0, (q - (len(logs) - 1)) / denominator) if denominator > 0 else 0.0


def _consistent(logs: np.ndarray, sigmas: np.ndarray) -> bool:
    """No two sources more than 3 combined standard deviations apart."""
    return all(abs(logs[i] - logs[j]) <= 3.0 * np.hypot(sigmas[i], sigmas[j])
               for i in range(len(logs)) for j in range(i + 1, len(logs)))


def odd_one_out(observations: list[ScaleObservation]) -> int | None:
    """The index (into observations) of the one usable source that disagrees with all the others while they
    agree among themselves (three or more usable sources, inconsistent together); None otherwise."""
    usable = [i for i, o in enumerate(observations) if o.usable()]
    if len(usable) < 3:
        return None
    logs = np.log([observations[i].value for i in usable])
    sigmas = np.array([observations[i].sigma for i in usable])
    if _consistent(logs, sigmas):
        return None
    odd = []
    for k in range(len(usable)):
        rest = np.arange(len(usable)) != k
        apart = all(abs(logs[k] - logs[j]) > 3.0 * np.hypot(sigmas[k], sigmas[j]) for j in np.flatnonzero(rest))
        if apart and _consistent(logs[rest], sigmas[rest]):
            odd.append(usable[k])
    return odd[0] if len(odd) == 1 else None


def fuse(observations: list[ScaleObservation], default: float = 1.0) -> ScaleEstimate:
    """The random-effects mean of the usable observations' log values (module docstring): each source's variance is
    its sigma^2 plus tau^2 (between_source_variance), the people's size error shared; `default` (source "default",
    sigma None) when none is usable. Sources that agree (chi^2 within its expectation) give the inverse-variance
    mean. Sources whose difference exceeds 3 standard deviations of their sampling errors make the estimate
    inconsistent, and its 2-sigma interval then reaches every source's value."""
    odd = odd_one_out(observations)
    if odd is not None:
        wrong = observations[odd]
        others = " and ".join(o.source for i, o in enumerate(observations) if o.usable() and i != odd)
        observations = list(observations)
        observations[odd] = dataclasses.replace(
            wrong, value=None, sigma=None, detail={**wrong.detail, "set_aside": {"value": wrong.value,
                                                                                 "sigma": wrong.sigma}},
            reason=f"set aside: {wrong.value:.4g} m per VO unit (+-{100 * wrong.sigma:.0f}%) disagrees with {others}, "
                   "which agree")
    usable = [o for o in observations if o.usable()]
    if not usable:
        return ScaleEstimate(float(default), None, "default", list(observations))
    logs = np.log([o.value for o in usable])
    sigmas = np.array([o.sigma for o in usable])
    consistent = _consistent(logs, sigmas)
    person = np.array([bool(o.person_size) for o in usable], dtype=bool)
    tau2 = between_source_variance(logs, sigmas, HETEROGENEITY_ALPHA)
    mean, sigma = _grouped(logs, sigmas ** 2 + tau2, person)
    if not consistent:  # never a tight interval around a value another source rejects
        sigma = max(sigma, float(np.max(np.abs(logs - mean))) / 2.0)
    return ScaleEstimate(float(np.exp(mean)), sigma, "+".join(o.source for o in usable), list(observations),
                         consistent, spread=float(np.sqrt(tau2)))


def _runs(mask: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the maximal runs of True in a 1-D bool array."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return [np.arange(start, stop) for start, stop in zip(edges[::2], edges[1::2])]


def scale_subjects(depths: list[np.ndarray], ratio: float = SUBJECT_DEPTH_RATIO,
                   min_frames: int = SUBJECT_MIN_FRAMES) -> np.ndarray:
    """Which people measure the camera scale (SUBJECT_DEPTH_RATIO): depths, per person, the camera-frame depths
    (metres) of its visible frames. A person is a subject when its median depth is within `ratio` of the nearest
    median among the people seen for min_frames frames (of all people when none is). Returns a bool per person."""
    medians = np.array([float(np.median(d)) if len(d) else np.inf for d in depths])
    counts = np.array([len(d) for d in depths])
    if not len(medians):
        return np.zeros(0, dtype=bool)
    steady = counts >= min_frames
    reference = medians[steady].min() if steady.any() else medians.min()
    return np.isfinite(medians) & (medians <= ratio * reference)


def floor_support(points: np.ndarray, plane: tuple[np.ndarray, float], contact_points_cam: list[list[np.ndarray]],
                  world_from_cam: np.ndarray, *, radius: float = FLOOR_RADIUS, every: int = 5) -> int:
    """How many of `points` (VO frame; the plane's inliers) lie within `radius` camera heights of a footprint: where
    the line of sight to a person's contacts (their mean, every `every`-th frame) meets the plane (n, d)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normal, offset = np.asarray(plane[0], dtype=np.float64), float(plane[1])
    near = np.zeros(len(points), dtype=bool)
    for per_frame in contact_points_cam:
        for t in range(0, len(per_frame), every):
            contacts = np.asarray(per_frame[t], dtype=np.float64).reshape(-1, 3)
            if not len(contacts):
                continue
            centre = world_from_cam[t, :3, 3]
            ray = world_from_cam[t, :3, :3] @ contacts.mean(axis=0)
            height, along = centre @ normal + offset, ray @ normal
            if height <= 0 or along >= 0:  # the camera under the plane, or a line of sight that never meets it
                continue
            footprint = centre - height / along * ray
            near |= np.linalg.norm(points - footprint, axis=1) < radius * height
    return int(near.sum())


def scale_from_planted_feet(joints_cam: list[np.ndarray], planted: list[np.ndarray], frames: list[np.ndarray],
                            world_from_cam: np.ndarray, *, depth_weight: float = DEPTH_WEIGHT,
                            huber: float = 0.05, iterations: int = 10, bootstrap: int = 200,
                            min_frames: int = 10, seed: int = 0) -> ScaleObservation:
    """The planted-feet observation (module docstring).

    Per track: joints_cam (n, C, 3) contact joints in each frame's camera (metres), planted (n, C) bool,
    frames (n,) indices into world_from_cam (T, 4, 4) (VO poses, translation in VO units). huber: metres.
    """
    obs = ScaleObservation("planted feet")
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    R, c = world_from_cam[:, :3, :3], world_from_cam[:, :3, 3]
    a_parts, b_parts, run_ids = [], [], []
    for joints, mask, idx in zip(joints_cam, planted, frames):
        joints, mask, idx = np.asarray(joints, np.float64), np.asarray(mask, bool), np.asarray(idx, np.int64)
        if joints.shape[:2] != mask.shape or len(idx) != len(mask):
            raise ValueError(f"joints_cam (n, C, 3), planted (n, C) and frames (n,) disagree: {joints.shape}, "
                             f"{mask.shape}, {idx.shape}")
        world_dir = np.einsum("nij,nkj->nki", R[idx], joints)  # R_t x_t
        for j in range(mask.shape[1]):
            for run in _runs(mask[:, j]):
                if len(run) < 2:
                    continue
                a = world_dir[run, j] - world_dir[run, j].mean(axis=0)
                b = c[idx[run]] - c[idx[run]].mean(axis=0)
                rot = R[idx[run]]  # residuals in each frame's camera axes, where the noise is anisotropic
                a_parts.append(np.einsum("nji,nj->ni", rot, a))
                b_parts.append(np.einsum("nji,nj->ni", rot, b))
                run_ids.append(np.full(len(run), len(run_ids)))
    if not a_parts:
        obs.reason = "no planted foot"
        return obs
    a, b, run_id = np.concatenate(a_parts), np.concatenate(b_parts), np.concatenate(run_ids)
    obs.frames = len(a)
    w3 = np.array([1.0, 1.0, depth_weight])

    def solve(rows: np.ndarray) -> float | None:
        aa, bb = a[rows], b[rows]
        weights = np.ones(len(aa))
        s = None
        for _ in range(iterations):
            den = np.sum(weights[:, None] * w3 * bb * bb)
            if den < 1e-18:
                return None
            s = -np.sum(weights[:, None] * w3 * aa * bb) / den
            residual = np.sqrt(np.sum(w3 * (aa + s * bb) ** 2, axis=1))
            weights = np.where(residual <= huber, 1.0, huber / np.maximum(residual, 1e-12))
        return float(s) if s is not None and s > 0 and np.isfinite(s) else None

    if len(a) < min_frames:
        obs.reason = f"{len(a)} planted-foot frames, fewer than {min_frames}"
        return obs
    value = solve(np.arange(len(a)))
    if value is None:
        obs.reason = "the camera does not move while a foot is planted" if np.sum(b * b) < 1e-18 else \
            "the planted feet give no positive scale"
        return obs
    rng = np.random.default_rng(seed)
    members = [np.flatnonzero(run_id == k) for k in range(len(a_parts))]
    samples = []
    for _ in range(bootstrap):
        pick = rng.integers(0, len(members), len(members))
        s = solve(np.concatenate([members[k] for k in pick]))
        samples.append(np.log(s) if s is not None else np.nan)
    samples = np.asarray(samples)
    failed = np.mean(~np.isfinite(samples))
    if len(members) < 3 or failed > 0.1:
        obs.reason = f"too few planted-foot runs for an uncertainty ({len(members)} runs)"
        obs.detail = {"fit": value, "runs": len(members)}
        return obs
    obs.value = value
    bootstrap_sigma = float(np.std(samples[np.isfinite(samples)]))
    obs.sigma = float(np.hypot(bootstrap_sigma, FEET_MODEL_SIGMA))
    obs.detail = {"runs": len(members), "bootstrap_sigma": bootstrap_sigma}
    return obs


def scale_from_gait(pelvis_cam: list[np.ndarray], strides: list[float | None], legs: list[float],
                    frames: list[np.ndarray], world_from_cam: np.ndarray, up: np.ndarray, *,
                    step_legs: float = GAIT_STEP_LEGS, step_sigma: float = GAIT_STEP_SIGMA) -> ScaleObservation:
    """The gait observation (module docstring).

    Per track: pelvis_cam (n, 3) the pelvis in each frame's camera (metres) over consecutive frames, strides its
    stride frequency in cycles a frame (None: the feet do not alternate), legs its leg length (m), frames (n,)
    indices into world_from_cam (T, 4, 4) (VO poses, translation in VO units); up (3,) the world's up in the VO
    frame. The people's estimates are fused in log with their variances (each person's step is his own)."""
    obs = ScaleObservation("gait")
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    if not np.linalg.norm(up) > 0:
        obs.reason = "no up direction"
        return obs
    up = up / np.linalg.norm(up)
    horizontal = np.eye(3) - np.outer(up, up)
    logs, variances, used, reasons = [], [], 0, []
    for pelvis, stride, leg, idx in zip(pelvis_cam, strides, legs, frames):
        idx = np.asarray(idx, np.int64)
        if stride is None or not stride > 0 or len(idx) < 8:
            reasons.append("no steady gait")
            continue
        R, c = world_from_cam[idx, :3, :3], world_from_cam[idx, :3, 3]
        own = np.einsum("nij,nj->ni", R, np.asarray(pelvis, np.float64))  # R_t p_t, metres
        t = np.arange(len(idx), dtype=np.float64)
        A = horizontal @ np.polyfit(t, c, 1)[0]    # VO units a frame
        B = horizontal @ np.polyfit(t, own, 1)[0]  # metres a frame
        target = 2.0 * stride * step_legs * leg    # metres a frame
        a2, ab, b2 = A @ A, A @ B, B @ B
        disc = ab * ab - a2 * (b2 - target * target)
        if a2 < 1e-18 or disc < 0:
            reasons.append("the camera does not move with the person")
            continue
        s = (-ab + np.sqrt(disc)) / a2
        along = (s * A + B) @ A
        if not s > 0 or along <= 0:
            reasons.append("the camera does not move with the person")
            continue
        sensitivity = target * target / (s * along)
        if sensitivity > GAIT_MAX_SENSITIVITY:
            reasons.append("the person's travel is mostly his own in the camera, not the camera's")
            continue
        path = (s * c + own) @ horizontal
        half = max(1, int(round(0.5 / stride)))  # one sample a step: the sway averages out
        coarse = path[::half]
        length = np.linalg.norm(np.diff(coarse, axis=0), axis=1).sum()
        if length > GAIT_MAX_PATH_RATIO * np.linalg.norm(coarse[-1] - coarse[0]):
            reasons.append("the walk is not straight")
            continue
        logs.append(np.log(s))
        # A step a person's travel barely follows still carries the whole step's error.
        variances.append((step_sigma * max(1.0, sensitivity)) ** 2 + GAIT_MODEL_SIGMA ** 2)
        used += len(idx)
    if not logs:
        obs.reason = "; ".join(sorted(set(reasons))) or "no track"
        return obs
    weights = 1.0 / np.asarray(variances)
    obs.value = float(np.exp(np.sum(weights * np.asarray(logs)) / weights.sum()))
    obs.sigma = float(1.0 / np.sqrt(weights.sum()))
    obs.frames = used
    obs.detail = {"people": len(logs), "step_legs": step_legs}
    return obs


def map_ground_plane(points: np.ndarray, world_from_cam: np.ndarray, up: np.ndarray, *, max_tilt_deg: float = 30.0,
                     inlier_fraction: float = 0.01, min_support: int = 50, hypotheses: int = 1000,
                     seed: int = 0) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The ground among the odometry's map points: the plane below the cameras with the most inliers among
    planes whose normal lies within max_tilt_deg of `up` (the people's upright direction in the VO frame),
    refined by total least squares on its inliers. Inliers lie within inlier_fraction of the median distance
    from the cameras to the points (the map has no metric unit). Returns (unit normal n pointing up, offset d
    with n . x + d = 0, inlier mask) or None when no such plane has min_support inliers."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    if len(points) < max(3, min_support) or not np.isfinite(up).all() or np.linalg.norm(up) == 0:
        return None
    up = up / np.linalg.norm(up)
    centres = world_from_cam[::max(1, len(world_from_cam) // 200), :3, 3]  # a long video: a subset will do
    threshold = inlier_fraction * float(np.median(np.linalg.norm(points - centres.mean(axis=0), axis=1)))
    rng = np.random.default_rng(seed)
    sample = rng.integers(0, len(points), (hypotheses, 3))
    p0, p1, p2 = points[sample[:, 0]], points[sample[:, 1]], points[sample[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals[ok] /= norms[ok, None]
    normals *= np.where(normals @ up < 0, -1.0, 1.0)[:, None]
    offsets = -np.einsum("ij,ij->i", normals, p0)
    below = np.median(centres @ normals.T + offsets, axis=0) > 0  # the cameras above the plane
    ok &= (normals @ up >= np.cos(np.radians(max_tilt_deg))) & below
    if not ok.any():
        return None
    candidates = np.flatnonzero(ok)
    counts = np.array([np.count_nonzero(np.abs(points @ normals[k] + offsets[k]) < threshold) for k in candidates])
    best = candidates[int(np.argmax(counts))]
    inliers = np.abs(points @ normals[best] + offsets[best]) < threshold
    for _ in range(2):  # total least squares on the inliers, then its own inliers
        if inliers.sum() < max(3, min_support):
            return None
        mean = points[inliers].mean(axis=0)
        normal = np.linalg.svd(points[inliers] - mean, full_matrices=False)[2][-1]
        normal = normal if normal @ up >= 0 else -normal
        offset = -float(normal @ mean)
        inliers = np.abs(points @ normal + offset) < threshold
    if inliers.sum() < min_support or np.median(centres @ normal + offset) <= 0:
        return None
    return normal, offset, inliers


def scale_from_camera_height(contact_points_cam: list[list[np.ndarray]], world_from_cam: np.ndarray,
                             plane: tuple[np.ndarray, float], *, floor_points: np.ndarray | None = None,
                             frames_per_sample: int = FRAMES_PER_SAMPLE, min_frames: int = 10) -> ScaleObservation:
    """The ground observation (module docstring): contact_points_cam per person, per frame of world_from_cam,
    (k, 3) points on the ground in that camera (metres); plane (n, d): the ground in the VO frame
    (map_ground_plane); floor_points: the map points the plane was fitted to, which must lie where the people
    stand (floor_support, FLOOR_SUPPORT; None: not checked). A person with fewer than min_frames frames of
    contacts above the ground is left out."""
    obs = ScaleObservation("ground")
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    normal, offset = np.asarray(plane[0], dtype=np.float64), float(plane[1])
    if floor_points is not None:
        support = floor_support(floor_points, plane, contact_points_cam, world_from_cam)
        obs.detail["floor_support"] = support
        if support < FLOOR_SUPPORT:
            obs.reason = (f"the map's ground plane has {support} points within {FLOOR_RADIUS:g} camera height of "
                          f"where the people stand (fewer than {FLOOR_SUPPORT}): not the floor they stand on "
                          "(a plain or reflective floor gives the odometry no points)")
            return obs
    heights_vo = world_from_cam[:, :3, 3] @ normal + offset
    normals_cam = np.einsum("tji,j->ti", world_from_cam[:, :3, :3], normal)  # the ground's normal in each camera
    centres, sigmas, heights, frames = [], [], [], 0
    for person, per_frame in enumerate(contact_points_cam):
        if len(per_frame) != len(world_from_cam):
            raise ValueError(f"contact_points_cam[{person}] has {len(per_frame)} frames, world_from_cam "
                             f"{len(world_from_cam)}")
        logs, metres = [], []
        for t, points in enumerate(per_frame):
            points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
            if not len(points):
                continue
            # The camera's height above the soles: the contact vertices' far end along the normal (the rest of a
            # foot's vertices lie up to its height above the ground).
            metric = float(np.quantile(-(points @ normals_cam[t]), SOLE_QUANTILE))
            if metric > 0 and heights_vo[t] > 0:
                logs.append(np.log(metric / heights_vo[t]))
                metres.append(metric)
        if len(logs) < min_frames:
            continue
        heights.append(float(np.median(metres)))
        logs = np.asarray(logs)
        centre = float(np.median(logs))
        spread = 1.4826 * float(np.median(np.abs(logs - centre)))
        centres.append(centre)
        sigmas.append(max(spread / np.sqrt(max(1.0, len(logs) / frames_per_sample)), 1e-3))
        frames += len(logs)
    obs.frames = frames
    if not centres:
        obs.reason = f"no person with {min_frames} frames of contacts above the map's ground"
        return obs
    people = len(centres)
    sampling = float(np.sqrt(np.sum(np.square(sigmas)))) / people
    scatter = float(np.std(centres, ddof=1)) / np.sqrt(people) if people > 1 else 0.0
    obs.value = float(np.exp(np.mean(centres)))
    obs.sigma = max(sampling, scatter)
    height = float(np.exp(np.mean(np.log(heights))))
    low, high = PLAUSIBLE_CAMERA_HEIGHT_M
    outside = max(0.0, float(np.log(height / high)), float(np.log(low / height)))
    obs.detail.update({"people": people, "per_person": [float(np.exp(c)) for c in centres],
                       "camera_height_m": height, "camera_height_suspect": outside > 0})
    if outside > 0:  # wrong by at least that ratio (module docstring)
        obs.detail["sampling_sigma"] = obs.sigma
        obs.sigma = float(np.hypot(obs.sigma, outside))
    return obs


def scale_from_depth(points: np.ndarray, world_from_cam: np.ndarray, depth_maps, intrinsics: np.ndarray, *,
                     min_samples: int = 50) -> ScaleObservation:
    """The depth-map observation: each map point seen in a frame (in front of the camera, inside the image)
    votes log(depth map at its pixel / its VO depth). depth_maps: (T, H, W) metric depths (0 or non-finite:
    unknown); intrinsics (4,) fx, fy, cx, cy of the depth maps' pixels."""
    obs = ScaleObservation("depth map", person_size=False)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    if len(depth_maps) != len(world_from_cam):
        raise ValueError(f"{len(depth_maps)} depth maps for {len(world_from_cam)} cameras")
    logs, per_frame = [], []
    for t, depth in enumerate(depth_maps):
        depth = np.asarray(depth, dtype=np.float64)
        x = to_camera(points, world_from_cam[t])
        front = x[:, 2] > 1e-9
        u, v = np.round(project(x[front], intrinsics)).astype(np.int64).T
        inside = (u >= 0) & (u < depth.shape[1]) & (v >= 0) & (v < depth.shape[0])
        metric = depth[v[inside], u[inside]]
        known = np.isfinite(metric) & (metric > 0)
        if known.any():
            votes = np.log(metric[known] / x[front][inside][known, 2])
            logs.append(votes)
            per_frame.append(float(np.median(votes)))
    votes = np.concatenate(logs) if logs else np.zeros(0)
    obs.frames = len(per_frame)
    if len(votes) < min_samples:
        obs.reason = f"{len(votes)} map points with a known depth, fewer than {min_samples}"
        return obs
    centre = float(np.median(votes))
    frame_spread = 1.4826 * float(np.median(np.abs(np.asarray(per_frame) - centre)))
    obs.value = float(np.exp(centre))
    obs.sigma = float(max(frame_spread / np.sqrt(max(1.0, len(per_frame) / FRAMES_PER_SAMPLE)), 0.01))
    return obs
