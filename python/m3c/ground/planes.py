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


def level_with_body_up(plane: PlaneFit, points, body_up, min_extent: float = 0.25) -> tuple[PlaneFit, bool]:
    """Takes the plane's tilt from the people's upright direction where the contact points cannot fix it.

    The tilt of a plane fitted to soles is fixed, along each in-plane direction, only as far as the points
    extend along it: over a short clip (a step or two) or a straight walk (a narrow strip), the soles' own tilt
    decides it, and a foot fitted a little rolled tilts the ground. Along each in-plane principal axis of the
    inliers with an rms extent below min_extent metres, the normal takes the slope of body_up (3,), the
    people's mean pelvis-to-neck direction (people stand and walk upright on average: sideways exactly, forward
    within a few degrees). Returns (plane, whether it was changed); the plane keeps passing through the points."""
    points = np.asarray(points, dtype=np.float64)[plane.inliers]
    up = np.asarray(body_up, dtype=np.float64)
    if len(points) < 3 or not np.isfinite(up).all() or np.linalg.norm(up) == 0:
        return plane, False
    up = up / np.linalg.norm(up)
    centred = points - points.mean(axis=0)
    in_plane = centred - np.outer(centred @ plane.normal, plane.normal)
    _, spread, axes = np.linalg.svd(in_plane, full_matrices=False)
    extent = spread[:2] / np.sqrt(len(points))  # rms extent along the two in-plane axes
    short = extent < min_extent
    if not short.any():
        return plane, False
    # The normal in the basis (axis 0, axis 1, fitted normal), with the slopes along short axes from body_up.
    coords = np.array([up @ axes[0] if short[0] else 0.0, up @ axes[1] if short[1] else 0.0,
                       abs(up @ plane.normal)])
    normal = coords[0] * axes[0] + coords[1] * axes[1] + coords[2] * plane.normal
    if np.linalg.norm(normal) < 1e-6:
        return plane, False
    normal /= np.linalg.norm(normal)
    heights = points @ normal
    offset = -float(np.median(heights))
    rms = float(np.sqrt(np.mean((heights + offset) ** 2)))
    return PlaneFit(normal=normal, offset=offset, inliers=plane.inliers, rms=rms), True


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
