"""DBSCAN and plane fitting on contact points, backed by the C++ core (cpp/ground).

Planes are {x : normal . x + offset = 0} with a unit normal oriented "up" (normal . up > 0):
normal . x + offset is the signed height of x above the plane, and offset is the height of the frame's
origin above it. "Up" is always an explicit argument, in the frame of the points: in the OpenCV camera frame
(x right, y down, z forward) it is CAMERA_UP = -y for a roughly upright camera; in a gravity-aligned world
frame, the world's up axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from m3c import _core

# Up in the OpenCV camera frame (y points down) when the camera is roughly upright. Only the normal's sign
# depends on it, so a tilted camera still gets correctly oriented floors.
CAMERA_UP = np.array([0.0, -1.0, 0.0])

_FILL_MODES = {"hold": _core.GapFill.hold, "linear": _core.GapFill.linear}
_GROUND = _core.GroundOptions()  # the defaults (cpp/ground), read from the core, never copied


@dataclass(frozen=True)
class GroundParams:
    """Settings of the ground stage; distances in metres.

    eps, min_samples: DBSCAN radius and core threshold (min_samples counts the point itself).
    robust: fit each cluster's plane with RANSAC (MSAC scoring) and refit on the inliers (|distance| <=
        inlier_threshold) by total least squares; False fits all points by total least squares.
    min_support: a cluster (robust: its inliers) needs at least this many points to yield a plane.
    max_iterations, confidence, seed: RANSAC sampling (deterministic for a given seed).
    max_distance: a person is associated with the plane whose median |distance| to its contact points (its
        foot points when it has any) is smallest, if that median is <= max_distance.
    fill: frames of a track without an observation take the most recent observed plane ("hold"), or
        interpolate between the observations around the gap ("linear"); frames before the first observation
        take the first one in both modes.
    """

    eps: float = _GROUND.eps
    min_samples: int = _GROUND.min_samples
    robust: bool = _GROUND.fit.robust
    inlier_threshold: float = _GROUND.fit.inlier_threshold
    min_support: int = _GROUND.fit.min_support
    max_iterations: int = _GROUND.fit.max_iterations
    confidence: float = _GROUND.fit.confidence
    seed: int = _GROUND.fit.seed
    max_distance: float = _GROUND.max_distance
    fill: str = _GROUND.fill.name

    def fit_options(self) -> "_core.PlaneFitOptions":
        if int(self.seed) < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        options = _core.PlaneFitOptions()
        options.robust = bool(self.robust)
        options.inlier_threshold = float(self.inlier_threshold)
        options.min_support = int(self.min_support)
        options.max_iterations = int(self.max_iterations)
        options.confidence = float(self.confidence)
        options.seed = int(self.seed)
        return options

    def core_options(self) -> "_core.GroundOptions":
        if self.fill not in _FILL_MODES:
            raise ValueError(f"fill must be one of {sorted(_FILL_MODES)}, got {self.fill!r}")
        options = _core.GroundOptions()
        options.eps = float(self.eps)
        options.min_samples = int(self.min_samples)
        options.fit = self.fit_options()
        options.max_distance = float(self.max_distance)
        options.fill = _FILL_MODES[self.fill]
        return options


def dbscan(points, eps: float, min_samples: int, *, return_core: bool = False):
    """DBSCAN clustering of points (N, 3), eps in metres, min_samples counting the point itself.

    Returns labels (N,) int64, -1 for noise; with return_core, (labels, is_core (N,) bool). Labels equal
    scikit-learn's DBSCAN (Euclidean metric): a neighbourhood holds the points at distance <= eps, and a
    border point within eps of cores of several clusters joins the cluster whose lowest-index core point
    comes first in the input, which is also the cluster with the smallest id. Empty input gives empty labels.
    """
    labels, is_core = _core.dbscan(points, float(eps), int(min_samples))
    return (labels, is_core) if return_core else labels


@dataclass(frozen=True)
class PlaneFit:
    normal: np.ndarray  # (3,) unit, normal . up > 0
    offset: float  # normal . x + offset = 0 on the plane, metres
    inliers: np.ndarray  # (N,) bool; all True without the robust option
    rms: float  # root mean square distance of the inliers to the plane, metres

    def signed_distance(self, points) -> np.ndarray:
        """Height above the plane (metres) of points (..., 3)."""
        return np.asarray(points, dtype=np.float64) @ self.normal + self.offset


def fit_plane(points, *, up, robust: bool = GroundParams.robust,
              inlier_threshold: float = GroundParams.inlier_threshold, min_support: int = GroundParams.min_support,
              max_iterations: int = GroundParams.max_iterations, confidence: float = GroundParams.confidence,
              seed: int = GroundParams.seed) -> PlaneFit:
    """Fits a plane to points (N, 3), metres; up (3,) in the points' frame orients the normal.

    Total least squares (the smallest right singular vector of the centred points); robust=True first finds
    the inliers with RANSAC. Raises ValueError when fewer than min_support points (or inliers) support the
    plane, or when the points are collinear.
    """
    params = GroundParams(robust=robust, inlier_threshold=inlier_threshold, min_support=min_support,
                          max_iterations=max_iterations, confidence=confidence, seed=seed)
    normal, offset, inliers, rms = _core.fit_plane(points, up, params.fit_options())
    return PlaneFit(normal=normal, offset=float(offset), inliers=inliers, rms=float(rms))


@dataclass(frozen=True)
class RayGroundParams:
    """The noise model of `fit_ground_along_rays` (defaults measured on the video benchmark, seeds 0-2).

    depth_error: relative error of a contact point's depth along its camera ray (the camera-local fit's depth
        wanders by 5-15% while its image position is accurate to pixels).
    correlated_frames: frames over which that error is one error (it swings at 0.6-1 Hz): each point's residual
        counts 1 / correlated_frames.
    roll_sigma, pitch_sigma: degrees, the prior's spread of the ground's tilt about the first camera's view
        axis (sideways: people are upright in the image, so their fitted spine holds it within a few degrees)
        and about its horizontal axis (forward: a monocular fit cannot see a person lean towards the camera,
        so the people's pitch is a weak guess).
    robust_scale: residuals beyond this many standard deviations count linearly (Huber).
    """

    depth_error: float = 0.1
    correlated_frames: float = 10.0
    roll_sigma: float = 3.0
    pitch_sigma: float = 20.0
    robust_scale: float = 2.0


def fit_ground_along_rays(points, centers, prior_up, sideways, params: RayGroundParams = RayGroundParams()
                          ) -> PlaneFit:
    """The ground through contact points whose error lies along their camera rays, with a prior on its tilt.

    points (N, 3): contact points, metres (one per person and frame: the mean of its contact vertices);
    centers (N, 3): the centre of the camera that saw each; prior_up (3,): the expected up direction;
    sideways (3,): the first camera's x axis (splits the prior's tilt into roll and pitch).

    A point is its camera centre plus its depth times its ray, and the depth is what is uncertain. The residual
    of a plane (n, d) is the relative depth error of the point against the ray's intersection with it,
    (n . x + d) / (n . c + d): the point's height over its camera's height. A perpendicular distance instead
    treats the scatter along the rays as ground: points of people at one distance from the camera, spread along
    their rays by the depth noise, are then best fitted by a plane through the camera (a camera on the floor).
    Along the tilt the points do not fix (all at one depth: the forward tilt; all in one place: any tilt) the
    prior (prior_up, RayGroundParams' sigmas) decides. Minimised with scipy's least_squares (Huber loss) over the
    normal's tilt from prior_up and the first camera's height. Raises ValueError for fewer than 3 points or
    non-finite input."""
    points = np.asarray(points, dtype=np.float64)
    centers = np.asarray(centers, dtype=np.float64)
    up, side = np.asarray(prior_up, dtype=np.float64), np.asarray(sideways, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or centers.shape != points.shape:
        raise ValueError(f"points and centers must both be (N, 3), got {points.shape} and {centers.shape}")
    if len(points) < 3:
        raise ValueError(f"a ground needs at least 3 contact points, got {len(points)}")
    if not (np.isfinite(points).all() and np.isfinite(centers).all() and np.isfinite(up).all()
            and np.isfinite(side).all()):
        raise ValueError("points, centers, prior_up and sideways must be finite")
    up = up / np.linalg.norm(up)
    roll_axis = side - (side @ up) * up  # tilting the normal along it rolls the ground about the view axis
    if np.linalg.norm(roll_axis) < 1e-6:
        raise ValueError("sideways must not be parallel to prior_up")
    roll_axis /= np.linalg.norm(roll_axis)
    pitch_axis = np.cross(up, roll_axis)
    origin = centers[0]
    weight = 1.0 / (params.depth_error * np.sqrt(params.correlated_frames))
    sigmas = np.radians([params.roll_sigma, params.pitch_sigma])

    def plane(x):
        normal = up + x[0] * roll_axis + x[1] * pitch_axis
        normal /= np.linalg.norm(normal)
        return normal, x[2] - normal @ origin  # x[2]: the first camera's height above the plane

    def residuals(x):
        normal, offset = plane(x)
        camera_heights = np.maximum(centers @ normal + offset, 1e-3)  # a camera under its ground is no answer
        return np.concatenate([weight * (points @ normal + offset) / camera_heights, np.arctan(x[:2]) / sigmas])

    start_height = float(np.median((origin - points) @ up))
    fit = least_squares(residuals, [0.0, 0.0, max(start_height, 0.1)], loss="huber", f_scale=params.robust_scale)
    normal, offset = plane(fit.x)
    heights = points @ normal + offset
    inliers = np.abs(fit.fun[:len(points)]) <= params.robust_scale  # the data residuals at the solution
    rms = float(np.sqrt(np.mean(heights[inliers] ** 2))) if inliers.any() else float("nan")
    return PlaneFit(normal=normal, offset=float(offset), inliers=inliers, rms=rms)


@dataclass(frozen=True)
class FramePlanes:
    labels: np.ndarray  # (N,) DBSCAN cluster per contact point, -1 = noise
    normals: np.ndarray  # (K, 3) one plane per cluster; zeros where not plane_ok
    offsets: np.ndarray  # (K,)
    plane_ok: np.ndarray  # (K,) bool: the cluster met the support rule
    person_plane: np.ndarray  # (P,) cluster id of each person's plane, -1 = none
    via_feet: np.ndarray  # (P,) bool: associated through foot contacts (only these count as observations)


def frame_planes(points, person, is_foot, *, up, num_people: int | None = None,
                 params: GroundParams | None = None) -> FramePlanes:
    """Ground planes of one frame.

    points (N, 3): every person's contact vertices (metres); person (N,) int: whose point it is (0..P-1);
    is_foot (N,) bool: the point is a foot vertex; up (3,); num_people defaults to max(person) + 1.
    Each person is associated with the closest plane by its foot points if it has any, else by all its points.
    """
    # Empty lists arrive as float64 arrays; the core only takes integer and boolean ones.
    person, is_foot = np.asarray(person), np.asarray(is_foot)
    if person.size == 0:
        person = person.astype(np.int64)
    if is_foot.size == 0:
        is_foot = is_foot.astype(bool)
    if num_people is None:
        num_people = int(person.max()) + 1 if person.size else 0
    labels, normals, offsets, plane_ok, person_plane, via_feet = _core.frame_planes(
        points, person, is_foot, int(num_people), up, (params or GroundParams()).core_options())
    return FramePlanes(labels, normals, offsets, plane_ok, person_plane, via_feet)
