"""The camera's focal length from its own motion, for videos whose intrinsics nobody gave.

A turning camera sees the same scene points under a rotation, and the image motion of a rotation depends on
the focal length: with the wrong focal the patch odometry's bundle adjustment cannot explain the measurements
and ends at a higher reprojection cost. So the search runs the first bundle adjustment of the patch VO (m3c.vo,
every keyframe of a window of frames, from the VO's own multi-start) at candidate focal lengths, on the same
Lucas-Kanade measurements (before its map exists the VO's front-end does not use the focal), and takes the focal
of the least cost. A camera that only translates (a dolly) or stands still leaves the cost flat: then the
estimate is marked uninformative and the caller keeps its default.

    estimate = estimate_focal(frames, masks)     # gray uint8 (T, H, W), people True in masks (T, H, W)
    estimate.focal, estimate.log_sigma, estimate.informative
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from m3c.io.video import default_intrinsics
from m3c.vo.odometry import VOConfig, check_settings, run_vo


@dataclass
class FocalSearchConfig:
    """Settings of estimate_focal (pixel quantities at the processing resolution, longer side <= max_image_side).

    windows: windows of consecutive frames whose costs are summed, spread evenly over the video;
    window_frames: frames per window; keyframe_flow_px: median image motion between the window's keyframes
    (the VO's init_min_flow_px); max_keyframes: keyframes per window (the first bundle adjustment's size);
    low, high: the coarse search range in units of the default focal (image diagonal), num_coarse log-spaced
    candidates, then num_refine candidates around the best; min_contrast: the cost rise at the ends of the
    search range (relative to the minimum) below which the cost is flat and the estimate uninformative (while the
    least cost lies within a step of an end whose rise is below it, the search goes on past that end, at most
    max_extension coarse steps);
    width_rise: the uncertainty (log_sigma) is the half-width in log(focal) of the cost's minimum where the cost
    has risen by this fraction; max_log_sigma: a wider minimum is uninformative too."""
    windows: int = 3
    window_frames: int = 40
    keyframe_flow_px: float = 6.0
    max_keyframes: int = 12
    low: float = 0.5
    high: float = 2.0
    num_coarse: int = 7
    num_refine: int = 4
    min_contrast: float = 0.10
    max_extension: int = 3
    max_log_sigma: float = 0.25
    width_rise: float = 0.02
    max_image_side: int = 640
    iterations: int = 30
    multi_start: bool = True

    def __post_init__(self):
        check_settings(self, {"windows": 1, "window_frames": 3, "max_keyframes": 3, "num_coarse": 3, "num_refine": 0,
                              "max_image_side": 16, "iterations": 1, "max_extension": 0},
                       ("keyframe_flow_px", "low", "high", "min_contrast", "max_log_sigma", "width_rise"),
                       strictly_positive=True, what="focal search: ")
        if not isinstance(self.multi_start, bool):
            raise TypeError(f"focal search: multi_start must be true or false, got {self.multi_start!r}")
        if not self.low < 1.0 < self.high:
            raise ValueError(f"focal search: need low < 1 < high (units of the default focal), got {self.low} and "
                             f"{self.high}")


@dataclass
class FocalEstimate:
    """focal: the estimate in pixels of the input frames (the default where uninformative); default: the
    default focal (image diagonal); ratio: focal / default; log_sigma: the uncertainty of log(focal), the
    half-width of the cost's minimum where it has risen by FocalSearchConfig.width_rise (inf when it does not
    bend upwards); informative: the cost located the focal; ratios, costs: every candidate tried (units of the
    default) and its summed bundle-adjustment cost; windows: the [start, stop) frames searched; message: why;
    still: no window moved the image enough for the odometry to start (a camera standing still)."""
    focal: float
    default: float
    log_sigma: float
    informative: bool
    ratios: np.ndarray = field(default_factory=lambda: np.zeros(0))
    costs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    windows: list[tuple[int, int]] = field(default_factory=list)
    message: str = ""
    still: bool = False

    @property
    def ratio(self) -> float:
        return self.focal / self.default

    def summary(self) -> dict:
        """JSON-ready: non-finite numbers (log_sigma where flat, the cost of a still window) become None."""
        def number(v):
            return float(v) if math.isfinite(v) else None

        return {"focal": float(self.focal), "default": float(self.default), "ratio": float(self.ratio),
                "log_sigma": number(self.log_sigma), "informative": bool(self.informative),
                "ratios": [float(r) for r in self.ratios], "costs": [number(c) for c in self.costs],
                "windows": [[int(a), int(b)] for a, b in self.windows], "message": self.message,
                "still": bool(self.still)}


def focal_windows(num_frames: int, config: FocalSearchConfig) -> list[tuple[int, int]]:
    """[start, stop) frame windows: config.windows of config.window_frames frames, spread evenly (fewer and
    shorter when the video is short, never overlapping)."""
    n = min(config.window_frames, num_frames)
    count = max(1, min(config.windows, num_frames // n))
    starts = np.linspace(0, num_frames - n, count).round().astype(int)
    return [(int(s), int(s) + n) for s in starts]


def _window_cost(frames: np.ndarray, masks: np.ndarray | None, focal: float, width: int, height: int,
                 config: FocalSearchConfig) -> float:
    """The robust cost of the VO's first bundle adjustment over one window's keyframes at this focal."""
    vo = VOConfig(max_image_side=config.max_image_side, init_frames=config.max_keyframes,
                  init_min_flow_px=config.keyframe_flow_px, init_iterations=config.iterations,
                  init_multi_start=config.multi_start, final_iterations=0,
                  window_iterations=1, refine_non_keyframes=False, use_depth=False,
                  hypotheses=1)  # the first bundle adjustment alone: one run
    k = np.array([focal, focal, width / 2.0, height / 2.0])
    result = run_vo(frames, masks=masks, intrinsics=k, config=vo)
    if result.static_camera:
        return math.nan
    return float(result.stats["init_ba_final_cost"])


def _fit_parabola(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(vertex, curvature a of y = a (x - vertex)^2 + c) of the least-squares parabola; curvature <= 0 when the
    points do not bend upwards."""
    a, b, _ = np.polyfit(x, y, 2)
    if not a > 0:
        return float(x[np.argmin(y)]), 0.0
    return float(-b / (2 * a)), float(a)


def reduce_frame(frame: np.ndarray, mask: np.ndarray | None, max_side: int, bgr: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """(gray uint8, mask bool or None) at the search's processing resolution (longer side <= max_side): the
    windows are held in memory, so they are kept as small as the odometry would make them anyway."""
    import cv2

    frame = np.asarray(frame)
    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY if bgr else cv2.COLOR_RGB2GRAY)
    height, width = gray.shape
    scale = min(1.0, max_side / max(width, height))
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        if mask is not None:
            mask = cv2.resize(np.asarray(mask, dtype=np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    return gray, None if mask is None else np.asarray(mask, dtype=bool)


def estimate_focal(frames: np.ndarray, masks: np.ndarray | None = None,
                   config: FocalSearchConfig | None = None, log=None) -> FocalEstimate:
    """The focal length (pixels) that best explains the camera's motion in `frames`.

    frames: uint8 (T, H, W) gray or (T, H, W, 3) RGB; masks: None or bool (T, H, W), True on people (hidden
    from the odometry as in the vo node). The windows are taken from the frames (focal_windows); the result is
    in pixels of the frames given. estimate_focal_windows takes windows already cut (and reduced) by the caller.
    """
    config = config or FocalSearchConfig()
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim not in (3, 4) or (frames.ndim == 4 and frames.shape[3] != 3):
        raise ValueError(f"frames must be uint8 (T, H, W) or (T, H, W, 3), got {frames.dtype} {frames.shape}")
    T, height, width = frames.shape[:3]
    if T < 3:
        raise ValueError(f"the focal search needs at least 3 frames of a moving camera, got {T}")
    if masks is not None:
        masks = np.asarray(masks)
        if masks.shape != (T, height, width):
            raise ValueError(f"masks must be (T, H, W) = {(T, height, width)} like the frames, got {masks.shape}")
    windows = focal_windows(T, config)
    clips = [(frames[a:b], None if masks is None else masks[a:b].astype(bool)) for a, b in windows]
    estimate = estimate_focal_windows(clips, width, height, config, log)
    estimate.windows = windows
    return estimate


def estimate_focal_windows(clips: list[tuple[np.ndarray, np.ndarray | None]], width: int, height: int,
                           config: FocalSearchConfig | None = None, log=None) -> FocalEstimate:
    """estimate_focal over windows of consecutive frames: clips = [(frames uint8 (n, h, w[, 3]), masks bool
    (n, h, w) or None), ...], each possibly reduced from the video's width x height (the focal is searched in
    units of the image diagonal, the same at any resolution); the result is in pixels of width x height."""
    config = config or FocalSearchConfig()
    if not clips:
        raise ValueError("the focal search needs at least one window of frames, got none")
    for k, (frames, masks) in enumerate(clips):
        frames = np.asarray(frames)
        if frames.dtype != np.uint8 or frames.ndim not in (3, 4) or len(frames) < 3:
            raise ValueError(f"window {k}: frames must be uint8 (n >= 3, h, w[, 3]), got {frames.dtype} "
                             f"{frames.shape}")
        if masks is not None and np.shape(masks) != frames.shape[:3]:
            raise ValueError(f"window {k}: masks must be (n, h, w) = {frames.shape[:3]}, got {np.shape(masks)}")
    if not (width > 0 and height > 0):
        raise ValueError(f"image size must be positive, got {width} x {height}")
    default = float(default_intrinsics(width, height)[0])
    failures: list[str] = []

    def window_cost(frames, masks, ratio):
        h, w = frames.shape[1:3]
        try:
            return _window_cost(frames, masks, ratio * float(np.hypot(w, h)), w, h, config)
        except ValueError as err:  # the odometry cannot run on this window (no texture outside the masks)
            failures.append(str(err))
            return math.nan

    # A window where the camera stood still (no frame moved the patches by keyframe_flow_px; the same at any
    # focal, the VO decides it before using the focal) has no cost: it is left out.
    start = [window_cost(frames, masks, 1.0) for frames, masks in clips]
    moving = [clip for clip, c in zip(clips, start) if math.isfinite(c)]
    if not moving:
        why = (f"the odometry could not run ({failures[0]})" if failures else "the camera did not move enough for "
               f"the odometry to start in any window ({config.keyframe_flow_px:g} px of image motion)")
        return FocalEstimate(default, default, math.inf, False, np.array([1.0]), np.array([math.nan]), [],
                             f"focal not observable: {why}; keeping the default {default:.0f} px",
                             still=not failures)
    tried: dict[float, float] = {1.0: float(sum(c for c in start if math.isfinite(c)))}

    def cost(ratio: float) -> float:
        key = round(float(ratio), 6)
        if key not in tried:
            tried[key] = float(sum(window_cost(frames, masks, key) for frames, masks in moving))
            if log:
                log(f"focal {key:.3f} x default ({key * default:.0f} px): cost {tried[key]:.4g}")
        return tried[key]

    coarse = list(np.exp(np.linspace(np.log(config.low), np.log(config.high), config.num_coarse)))
    step = np.log(coarse[1] / coarse[0])
    costs = [cost(r) for r in coarse]
    # A minimum near an end of the range, where the cost barely rises while it rises at the other end, may lie
    # beyond it (a wide-angle phone camera is about 0.55 x the diagonal): search on past that end.
    for _ in range(config.max_extension):
        if not np.isfinite(costs).all():
            break
        best = int(np.argmin(costs))
        rises = [c >= (1.0 + config.min_contrast) * costs[best] for c in (costs[0], costs[-1])]
        if best <= 1 and not rises[0] and rises[1]:
            coarse.insert(0, coarse[0] * math.exp(-step))
            costs.insert(0, cost(coarse[0]))
        elif best >= len(coarse) - 2 and not rises[1] and rises[0]:
            coarse.append(coarse[-1] * math.exp(step))
            costs.append(cost(coarse[-1]))
        else:
            break
    coarse, costs = np.array(coarse), np.array(costs)
    if not np.isfinite(costs).all():  # not expected (whether the VO starts does not depend on the focal)
        return FocalEstimate(default, default, math.inf, False, coarse, costs, [],
                             "focal not observable: the odometry gave no cost at some candidate focal lengths; "
                             f"keeping the default {default:.0f} px")
    best = int(np.argmin(costs))
    contrast = min(costs[0], costs[-1]) / costs[best] - 1.0 if costs[best] > 0 else 0.0
    if config.num_refine:
        lo = max(np.log(coarse[best]) - step, np.log(coarse[0]))
        hi = min(np.log(coarse[best]) + step, np.log(coarse[-1]))
        for r in np.exp(np.linspace(lo, hi, config.num_refine + 2)[1:-1]):
            cost(r)
    ratios = np.array(sorted(tried))
    all_costs = np.array([tried[r] for r in ratios])
    best = int(np.argmin(all_costs))
    x = np.log(ratios)
    at_end = best in (0, len(ratios) - 1)
    if not at_end:
        # The parabola through the least cost and its two neighbours; its vertex stays between the neighbours.
        near = slice(best - 1, best + 2)
        vertex, a = _fit_parabola(x[near], all_costs[near])
        vertex = float(np.clip(vertex, x[best - 1], x[best + 1]))
    else:
        vertex, a = float(x[best]), 0.0
    # Uncertainty: the half-width in log(focal) over which the fitted parabola rises by width_rise of the minimum
    # cost (the measurements' errors are correlated along patch tracks, so a formal curvature-based variance
    # would be overconfident; the width is what the benchmark's errors are compared against).
    log_sigma = math.sqrt(config.width_rise * all_costs[best] / a) if a > 0 else math.inf
    informative = contrast >= config.min_contrast and log_sigma <= config.max_log_sigma and not at_end
    if informative:
        focal = float(np.exp(vertex)) * default
        message = (f"focal {focal:.0f} px ({focal / default:.2f} x the default {default:.0f} px), log-sigma "
                   f"{log_sigma:.3f}; the cost rises {100 * contrast:.0f}% towards the ends of the search")
    else:
        focal = default
        if contrast < config.min_contrast:
            why = (f"the cost is flat: it rises only {100 * contrast:.1f}% from its minimum at {ratios[best]:.2f} x "
                   f"default towards the ends of the search (need {100 * config.min_contrast:.0f}%)")
        elif at_end:
            why = (f"the cost's minimum lies at the end of the search range ({ratios[0]:.2f}..{ratios[-1]:.2f} x "
                   "default)")
        else:
            why = f"the cost's minimum is too wide (log-sigma {log_sigma:.2f} > {config.max_log_sigma:g})"
        message = f"focal not observable from this camera motion: {why}; keeping the default {default:.0f} px"
    return FocalEstimate(focal, default, log_sigma, informative, ratios, all_costs, [], message)


def camera_focal_log_sigma(camera: dict) -> float:
    """The uncertainty in log(focal) of the focal length a camera record (the focal node's output) goes on with:
    0 for given intrinsics; the search's, the scene's lines' (their frames' half-interquartile range over 0.674, or
    one frame's own where larger: SceneCamera.log_sigma) or the people's (fused with the default, at
    GroundFocalConfig's default weights) where one of them set it; the spread of real cameras' focal lengths around
    the default (GroundFocalConfig.prior_log_sigma) otherwise."""
    from m3c.vo.ground_focal import GroundFocalConfig

    source = camera.get("source")
    if source == "given":
        return 0.0
    feet = GroundFocalConfig()
    record = {"estimated": camera.get("focal_estimate"), "scene": camera.get("scene"),
              "people": camera.get("feet_focal")}.get(source) or {}
    if source in ("estimated", "scene") and record.get("log_sigma") is not None:
        return float(record["log_sigma"])
    if source == "scene" and record.get("spread") is not None:  # a record written before log_sigma
        return float(record["spread"]) / 0.674
    if source == "people" and record.get("log_sigma") is not None:
        return float(1.0 / math.sqrt(sum(feet.fusion_weights(float(record["log_sigma"])))))
    return feet.prior_log_sigma
