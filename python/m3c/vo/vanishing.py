"""The focal length and the up direction of a camera from the scene's straight lines (vanishing points).

A still or translating camera cannot tell its focal length from its motion (m3c.vo.focal), but a built scene
can: its vertical edges meet at the vertical vanishing point v and each family of parallel horizontal edges
(court lines, a table, a window sill) at a vanishing point h on the horizon, and the two directions are
perpendicular. With the principal point c at the image centre, (v - c) . (h - c) = -f^2 in pixels (Caprile and
Torre's orthocentre relation for two vanishing points), so one well-supported pair gives f; the vertical
vanishing point then gives the up direction in the camera at any focal length (K^-1 v), which is the ground's
tilt without a single contact point.

Per frame: OpenCV's line segment detector (people's pixels removed), the vertical vanishing point by RANSAC over
the segments within max_vertical_tilt of the image's vertical (a camera held about upright), then the horizontal
one by RANSAC over the other segments, each hypothesis taken only where it is perpendicular to the vertical one
for a focal length within [low, high] x the image diagonal; inliers are segments whose direction points at the
vanishing point within inlier_degrees; the supports are refined by least squares over their lines. Over a video:
the frames' estimates are pooled by the median, and the estimate is informative when enough frames gave one and
they agree (relative half-interquartile range within max_spread). A camera held level (vertical edges parallel in
the image) leaves the focal length unobservable from this pair (v at infinity): no estimate.

    estimate = estimate_scene_camera(frames, masks)   # gray uint8 frames, people True in masks (or None)
    estimate.focal, estimate.informative, estimate.up(focal)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from m3c.vo.odometry import check_settings


@dataclass
class SceneLineConfig:
    """Settings of estimate_scene_camera (lengths as fractions of the image diagonal).

    min_length: shortest segment used; max_vertical_tilt: degrees from the image's vertical within which a
    segment may be a vertical edge (horizontal edges are taken between min_horizontal_tilt and max_horizontal_tilt:
    an edge nearly level in the image is parallel to it, and its vanishing point too far off to tell a focal
    length); min_vertical_distance: the vertical vanishing point lies at least this far from the image centre
    (x the diagonal; nearer, the lines are rather a horizontal direction receding from a camera looking down
    along it, e.g. a table's long edges in a portrait view); min_camera_tilt: degrees the camera must look up or
    down for the pair to give a focal length (a level camera's vertical vanishing point lies at infinity and the
    focal length's error grows as 1 / tan(tilt)); inlier_degrees: a segment supports a vanishing point when its
    direction points at it within this angle; min_vertical, min_horizontal: inliers each vanishing point needs;
    low, high: the focal lengths a pair may imply (x the diagonal); iterations: RANSAC draws per vanishing point;
    frames: frames sampled evenly over the video; min_frames: frames that must give an estimate; max_spread: half
    the interquartile range of the frames' focal lengths over their median above which the estimate is not
    informative; max_focal_log_sigma: a frame's focal length counts only where its supporting segments hold it
    within this (the jackknife's standard deviation of log f: on the video benchmark's seeds 0, 2 and 4 the ten
    frames above 0.1 were 0.49-0.86x or 1.70-2.46x the true focal length, and seed 9's still camera's six segments
    put it at 2x); max_image_side: frames are searched for segments at most this large (longer sides are scaled
    down; the geometry stays in the frame's pixels); seed: the RANSAC draws."""

    min_length: float = 0.02
    max_vertical_tilt: float = 25.0
    min_horizontal_tilt: float = 10.0
    max_horizontal_tilt: float = 75.0
    min_vertical_distance: float = 1.0
    min_camera_tilt: float = 2.0
    inlier_degrees: float = 1.5
    min_vertical: int = 6
    min_horizontal: int = 6
    low: float = 0.3
    high: float = 2.0
    iterations: int = 500
    frames: int = 9
    min_frames: int = 5
    max_image_side: int = 1280
    max_spread: float = 0.05
    max_focal_log_sigma: float = 0.1
    seed: int = 0

    def __post_init__(self):
        check_settings(self, {"min_vertical": 2, "min_horizontal": 2, "iterations": 1, "frames": 1, "min_frames": 1,
                              "max_image_side": 64},
                       ("min_length", "max_vertical_tilt", "inlier_degrees", "low", "high", "max_spread",
                        "min_camera_tilt", "max_focal_log_sigma"),
                       strictly_positive=True, what="scene lines: ")
        if not self.low < self.high:
            raise ValueError(f"scene lines: low ({self.low}) must be below high ({self.high})")
        if not 0 <= self.min_horizontal_tilt < self.max_horizontal_tilt <= 90 or not self.max_vertical_tilt < 90:
            raise ValueError("scene lines: the tilts must lie in [0, 90) degrees")


@dataclass
class FrameLines:
    """One frame's vanishing points, homogeneous in centred pixels over the diagonal ((x - cx) / d, (y - cy) / d,
    w), unit length; horizontal None when no supported one is perpendicular to the vertical one."""

    frame: int
    vertical: np.ndarray
    vertical_inliers: int
    horizontal: np.ndarray | None = None
    horizontal_inliers: int = 0
    focal: float | None = None  # pixels, from the pair
    focal_sigma: float | None = None  # log-focal standard deviation from the supporting segments (jackknife)


@dataclass
class SceneCamera:
    """The pooled estimate: focal (pixels, the median of the frames' or None), informative, the frames' own
    estimates (FrameLines) and why it is or is not informative."""

    width: int
    height: int
    frames: list[FrameLines] = field(default_factory=list)
    focal: float | None = None
    spread: float | None = None
    log_sigma: float | None = None  # of log(focal): the frames' spread or one frame's segments, the larger
    informative: bool = False
    reason: str = ""

    def up(self, focal: float, frame: int | None = None) -> np.ndarray | None:
        """The up direction (unit, OpenCV camera axes: y down) in frame `frame`'s camera (default: every frame's,
        averaged, which is a still camera's) at focal length `focal`; None without a vertical vanishing point."""
        ups = [_up_from_vertical(f.vertical, focal, self.diagonal) for f in self.frames
               if frame is None or f.frame == frame]
        if not ups:
            return None
        mean = np.mean(ups, axis=0)
        return mean / np.linalg.norm(mean)

    @property
    def diagonal(self) -> float:
        return float(np.hypot(self.width, self.height))

    def summary(self, focal: float | None = None) -> dict:
        """JSON-able record; with `focal`, each frame's up direction in its camera at that focal length too."""
        out = {"focal": self.focal, "informative": self.informative, "spread": self.spread,
               "log_sigma": self.log_sigma, "reason": self.reason,
               "frames": [{"frame": f.frame, "focal": f.focal, "focal_log_sigma": _finite_or_none(f.focal_sigma),
                           "vertical_inliers": f.vertical_inliers, "horizontal_inliers": f.horizontal_inliers}
                          for f in self.frames]}
        if focal is not None:
            for entry, f in zip(out["frames"], self.frames):
                entry["up"] = _up_from_vertical(f.vertical, focal, self.diagonal).tolist()
        return out


def _finite_or_none(value: float | None) -> float | None:
    """JSON has no infinity: an unbounded uncertainty (a refit admits no focal length) is written as null."""
    return value if value is not None and math.isfinite(value) else None


# Frames' up directions agree (one camera pose, true vertical edges) within this RMS angle, degrees: the ground's
# tilt prior (m3c.ground.world_frame.scene_up_prior) and a still camera's vertical (m3c.vo.ground_focal) both ask it.
MAX_UP_SPREAD = 3.0


def pooled_direction(directions) -> tuple[np.ndarray, float]:
    """(the mean unit direction, the RMS angle in degrees of the directions (n, 3), unit, from it): how well
    several frames' up directions agree."""
    directions = np.asarray(directions, dtype=np.float64)
    mean = directions.mean(axis=0)
    mean /= np.linalg.norm(mean)
    return mean, float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(directions @ mean, -1.0, 1.0)) ** 2))))


def agreeing_direction(directions, max_spread: float = MAX_UP_SPREAD) -> tuple[np.ndarray | None, float, np.ndarray]:
    """(the pooled unit direction or None, its RMS spread in degrees, which of the directions (n, 3) it pools) of
    several frames' up directions, a frame whose vertical vanishing point is another family of edges left out: the
    frames within 2 x max_spread degrees of the medoid (the direction nearest all others) are pooled, and the
    result counts (not None) when they are at least two and more than half of the frames and agree within
    max_spread.
    On the video benchmark one sampled frame in ten or so finds a vanishing point 5-20 degrees off (its
    neighbours within 1-2 degrees of the truth), which alone pushed the RMS spread over 3 degrees."""
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(directions) < 2:
        return None, math.nan, np.ones(len(directions), dtype=bool)
    angles = np.degrees(np.arccos(np.clip(directions @ directions.T, -1.0, 1.0)))
    medoid = directions[np.argmin(angles.sum(axis=1))]
    kept = np.degrees(np.arccos(np.clip(directions @ medoid, -1.0, 1.0))) <= 2.0 * max_spread
    mean, spread = pooled_direction(directions[kept])
    if kept.sum() < 2 or 2 * kept.sum() <= len(directions) or spread > max_spread:
        return None, spread, kept
    return mean, spread, kept


def _up_from_vertical(vertical: np.ndarray, focal: float, diagonal: float) -> np.ndarray:
    x, y, w = vertical
    up = np.array([diagonal * x, diagonal * y, focal * w])
    up /= np.linalg.norm(up)
    return up if up[1] < 0 else -up  # the camera's y axis points down


def line_segments(gray: np.ndarray, mask: np.ndarray | None = None, min_length: float = 0.02) -> np.ndarray:
    """(N, 4) segments x0, y0, x1, y1 of a gray uint8 image (OpenCV's line segment detector), at least
    min_length x the diagonal long, none with its midpoint or an end on a True pixel of `mask`."""
    import cv2

    gray = np.asarray(gray)
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"line_segments needs a gray uint8 image (H, W), got {gray.dtype} {gray.shape}")
    found = cv2.createLineSegmentDetector().detect(gray)[0]
    if found is None:
        return np.zeros((0, 4))
    segments = found.reshape(-1, 4).astype(np.float64)
    delta = segments[:, 2:] - segments[:, :2]
    keep = np.hypot(delta[:, 0], delta[:, 1]) >= min_length * np.hypot(*gray.shape)
    if mask is not None:
        if mask.shape != gray.shape:
            raise ValueError(f"mask {mask.shape} and image {gray.shape} differ in size")
        h, w = gray.shape
        for t in (0.0, 0.5, 1.0):
            p = segments[:, :2] + t * delta
            keep &= ~mask[np.clip(p[:, 1].astype(int), 0, h - 1), np.clip(p[:, 0].astype(int), 0, w - 1)]
    return segments[keep]


def _lines(segments: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """Unit homogeneous lines through each segment, in centred pixels over `scale`."""
    p = np.c_[(segments[:, :2] - centre) / scale, np.ones(len(segments))]
    q = np.c_[(segments[:, 2:] - centre) / scale, np.ones(len(segments))]
    lines = np.cross(p, q)
    return lines / np.linalg.norm(lines, axis=1, keepdims=True)


def _pointing(segments: np.ndarray, point: np.ndarray, centre: np.ndarray, scale: float, degrees: float
              ) -> np.ndarray:
    """Which segments point at the homogeneous `point` (centred over `scale`) within `degrees`: the sine of the
    angle between each segment and the line from its midpoint to the point."""
    mid = 0.5 * (segments[:, :2] + segments[:, 2:])
    direction = segments[:, 2:] - segments[:, :2]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    x, y, w = point
    towards = np.c_[x * scale + centre[0] * w, y * scale + centre[1] * w] - mid * w
    norm = np.linalg.norm(towards, axis=1)
    sine = np.abs(direction[:, 0] * towards[:, 1] - direction[:, 1] * towards[:, 0]) / np.maximum(norm, 1e-12)
    return sine < np.sin(np.radians(degrees))


def _refine(lines: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The point nearest to all the lines (weighted least squares on l . v = 0, |v| = 1)."""
    point = np.linalg.svd(lines * np.sqrt(weights)[:, None], full_matrices=False)[2][-1]
    return point / np.linalg.norm(point)


def _focal_squared(vertical: np.ndarray, horizontal: np.ndarray) -> float:
    """f^2 over the diagonal^2 from two perpendicular directions' vanishing points (negative: not perpendicular
    for any focal length)."""
    return float(-(vertical[0] * horizontal[0] + vertical[1] * horizontal[1]) / (vertical[2] * horizontal[2]))


def frame_vanishing_points(gray: np.ndarray, mask: np.ndarray | None = None,
                           config: SceneLineConfig | None = None, frame: int = 0) -> FrameLines | None:
    """One frame's vertical and (when one is perpendicular to it) horizontal vanishing point, or None when the
    vertical one lacks support."""
    config = config or SceneLineConfig()
    rng = np.random.default_rng(config.seed)
    h, w = np.asarray(gray).shape[:2]
    centre, scale = np.array([w / 2.0, h / 2.0]), float(np.hypot(w, h))
    factor = min(1.0, config.max_image_side / max(h, w))
    if factor < 1.0:  # the detector's time grows with the pixels; its segments are scaled back
        import cv2

        size = (max(1, round(w * factor)), max(1, round(h * factor)))
        small = cv2.resize(np.asarray(gray), size, interpolation=cv2.INTER_AREA)
        small_mask = None if mask is None else cv2.resize(mask.astype(np.uint8), size,
                                                          interpolation=cv2.INTER_NEAREST).astype(bool)
        segments = line_segments(small, small_mask, config.min_length)
        segments *= np.tile([w / size[0], h / size[1]], 2)
    else:
        segments = line_segments(gray, mask, config.min_length)
    if len(segments) < config.min_vertical:
        return None
    delta = segments[:, 2:] - segments[:, :2]
    tilt = np.degrees(np.arctan2(np.abs(delta[:, 0]), np.abs(delta[:, 1])))  # 0: the image's vertical
    length = np.hypot(delta[:, 0], delta[:, 1])
    lines = _lines(segments, centre, scale)

    def ransac(candidates: np.ndarray, accept) -> tuple[np.ndarray | None, np.ndarray]:
        index = np.flatnonzero(candidates)
        best, best_support = None, 0.0
        if len(index) < 2:
            return None, np.zeros(len(segments), bool)
        for _ in range(config.iterations):
            i, j = rng.choice(index, 2, replace=False)
            point = np.cross(lines[i], lines[j])
            if np.linalg.norm(point) < 1e-12 or not accept(point / np.linalg.norm(point)):
                continue
            inliers = candidates & _pointing(segments, point / np.linalg.norm(point), centre, scale,
                                             config.inlier_degrees)
            support = length[inliers].sum()
            if support > best_support:
                best, best_support = point / np.linalg.norm(point), support
        if best is None:
            return None, np.zeros(len(segments), bool)
        inliers = candidates & _pointing(segments, best, centre, scale, config.inlier_degrees)
        return _refine(lines[inliers], length[inliers]), inliers

    def far(point):
        return abs(point[2]) * config.min_vertical_distance <= np.hypot(point[0], point[1])

    vertical, v_inliers = ransac(tilt <= config.max_vertical_tilt, far)
    if vertical is None or v_inliers.sum() < config.min_vertical or not far(vertical):
        return None
    out = FrameLines(frame, vertical, int(v_inliers.sum()))
    if abs(vertical[2]) < 1e-9:
        return out  # vertical edges parallel in the image: no focal length from this pair

    def perpendicular(point):
        if abs(point[2]) < 1e-12:
            return False
        f2 = _focal_squared(vertical, point)
        return config.low ** 2 <= f2 <= config.high ** 2

    receding = (tilt > config.min_horizontal_tilt) & (tilt < config.max_horizontal_tilt)
    horizontal, h_inliers = ransac(~v_inliers & receding, perpendicular)
    if horizontal is None or h_inliers.sum() < config.min_horizontal or not perpendicular(horizontal):
        return out
    out.horizontal, out.horizontal_inliers = horizontal, int(h_inliers.sum())
    focal = float(np.sqrt(_focal_squared(vertical, horizontal)))
    tilt = np.degrees(np.arctan2(focal * abs(vertical[2]), np.hypot(vertical[0], vertical[1])))
    if tilt >= config.min_camera_tilt:
        out.focal = focal * scale
        out.focal_sigma = _jackknife_log_sigma(lines, length, v_inliers, h_inliers, vertical, horizontal)
    return out


def _jackknife_log_sigma(lines: np.ndarray, length: np.ndarray, v_inliers: np.ndarray, h_inliers: np.ndarray,
                         vertical: np.ndarray, horizontal: np.ndarray) -> float:
    """The jackknife standard deviation of log f over the segments that support the two vanishing points (vertical,
    horizontal: their refits over all of them): each segment left out in turn and its point refitted. A few
    segments meeting at a narrow angle can put a vanishing point anywhere along their common direction; leaving one
    out shows it. Infinite where a refit admits no focal length."""
    groups = ((np.flatnonzero(v_inliers), horizontal), (np.flatnonzero(h_inliers), vertical))
    if min(len(index) for index, _ in groups) < 3:  # one left out leaves a single line: any point on it
        return math.inf
    variance = 0.0  # the two groups' jackknife variances, (n - 1) / n sum (x_j - mean)^2, add
    for index, other in groups:
        logs = []
        for j in range(len(index)):
            keep = np.delete(index, j)
            f2 = _focal_squared(_refine(lines[keep], length[keep]), other)  # symmetric in its two points
            if not (f2 > 0 and np.isfinite(f2)):
                return math.inf
            logs.append(0.5 * math.log(f2))
        logs = np.asarray(logs)
        variance += (len(logs) - 1) / len(logs) * ((logs - logs.mean()) ** 2).sum()
    return float(math.sqrt(variance))


def estimate_scene_camera(frames, masks=None, config: SceneLineConfig | None = None,
                          frame_ids: list[int] | None = None) -> SceneCamera:
    """The pooled estimate over gray uint8 frames (a sequence of (H, W)), with optional people masks (True where
    a person is) of the same size; frame_ids name the frames in the result (default 0, 1, ...)."""
    config = config or SceneLineConfig()
    frames = list(frames)
    if not frames:
        raise ValueError("estimate_scene_camera needs at least one frame")
    h, w = np.asarray(frames[0]).shape[:2]
    masks = [None] * len(frames) if masks is None else list(masks)
    ids = list(range(len(frames))) if frame_ids is None else list(frame_ids)
    if len(masks) != len(frames) or len(ids) != len(frames):
        raise ValueError(f"{len(frames)} frames, {len(masks)} masks and {len(ids)} frame ids: give one of each")
    found = [r for r in (frame_vanishing_points(g, m, config, i) for g, m, i in zip(frames, masks, ids))
             if r is not None]
    out = SceneCamera(int(w), int(h), found)
    paired = [f for f in found if f.focal is not None]
    kept = [f for f in paired if f.focal_sigma <= config.max_focal_log_sigma]
    loose = (f" ({len(paired) - len(kept)} more whose segments leave it loose: log-sigma over "
             f"{config.max_focal_log_sigma:g})" if len(kept) < len(paired) else "")
    if len(kept) < config.min_frames:
        out.reason = (f"{len(kept)} of {len(frames)} frames gave a focal length (vertical and perpendicular "
                      f"horizontal edges){loose}, {config.min_frames} needed")
        return out
    focals = np.array([f.focal for f in kept])
    q25, median, q75 = np.percentile(focals, [25, 50, 75])
    out.focal, out.spread = float(median), float(0.5 * (q75 - q25) / median)
    # A still camera's frames repeat the same edges, so their agreement is not independent evidence: the
    # uncertainty is at least one frame's own (the median frame's jackknife), whatever the frames' spread.
    out.log_sigma = max(out.spread / 0.674, float(np.median([f.focal_sigma for f in kept])))
    out.informative = out.spread <= config.max_spread
    out.reason = (f"{len(kept)} of {len(frames)} frames{loose}, focal {median:.0f} px, spread "
                  f"{100 * out.spread:.1f}% ({'within' if out.informative else 'over'} {100 * config.max_spread:.0f}%)"
                  f", log-sigma {out.log_sigma:.2f}")
    return out
