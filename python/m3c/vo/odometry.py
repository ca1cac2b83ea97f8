"""Public API of the patch visual odometry (the C++ core behind m3c._core.run_patch_vo / PatchVO)."""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields
from numbers import Integral, Real

import numpy as np

from m3c import _core


def check_settings(settings, integers: dict[str, int], numbers: tuple[str, ...], strictly_positive: bool = False,
                   what: str = "") -> None:
    """Raises ValueError naming the first setting of a settings dataclass that is not an integer (bool excluded)
    >= its least value (`integers`: name -> least), or not a finite number >= 0 (> 0 if strictly_positive).
    `what` prefixes the message (e.g. "focal search: ")."""
    for name, least in integers.items():
        value = getattr(settings, name)
        if isinstance(value, bool) or not isinstance(value, Integral) or value < least:
            raise ValueError(f"{what}{name} must be an integer >= {least}, got {value!r}")
    for name in numbers:
        value = getattr(settings, name)
        if (isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(value) or value < 0
                or (strictly_positive and value == 0)):
            raise ValueError(f"{what}{name} must be a finite number {'>' if strictly_positive else '>='} 0, "
                             f"got {value!r}")


# The settings' defaults are the C++ core's (cpp/vo/patch_vo.h), read from it, never copied.
_VO = _core.PatchVOOptions()
_LK = _VO.lucas_kanade


@dataclass
class VOConfig:
    """Patch VO settings (pixel quantities at the processing resolution, longer side <= max_image_side).

    The patch graph is DPVO's; DPVO's numbers (96 patches, lifetime 13, window 10, removal 22, keyframe
    index 4) are sized for a GPU, the defaults here for a CPU (64, 10, 8, 16, 4).
    """
    max_image_side: int = _VO.max_image_side
    patches_per_frame: int = _VO.patches_per_frame
    patch_lifetime: int = _VO.patch_lifetime
    backward_frames: int = _VO.backward_frames
    optimization_window: int = _VO.optimization_window
    removal_window: int = _VO.removal_window
    keyframe_index: int = _VO.keyframe_index
    keyframe_threshold_px: float = _VO.keyframe_threshold_px
    new_keyframe_flow_px: float = _VO.new_keyframe_flow_px
    init_frames: int = _VO.init_frames
    init_min_flow_px: float = _VO.init_min_flow_px
    init_iterations: int = _VO.init_iterations
    init_multi_start: bool = _VO.init_multi_start
    window_iterations: int = _VO.window_iterations
    final_iterations: int = _VO.final_iterations
    loss_scale_px: float = _VO.loss_scale_px
    outlier_threshold_px: float = _VO.outlier_threshold_px
    refine_non_keyframes: bool = _VO.refine_non_keyframes
    use_depth: bool = _VO.use_depth
    num_threads: int = _VO.num_threads
    # Front-end (Lucas-Kanade + gradient-biased sampling).
    lk_window_px: int = _LK.window_px
    lk_pyramid_levels: int = _LK.pyramid_levels
    forward_backward_px: float = _LK.forward_backward_px
    reject_masked: bool = _LK.reject_masked
    mask_dilation_px: int = _LK.sampling.mask_dilation_px
    gradient_pool_px: int = _LK.sampling.pool_px
    min_gradient: float = _LK.sampling.min_gradient
    seed: int = _LK.seed
    # The odometry runs this many times, with patch-sampling seeds seed, seed + 1, ..., and keeps the run that
    # explains its own measurements best (least keyframe reprojection rms): on rendered video one run in 12-18
    # starts on a wrong motion that it then keeps (a camera that pans read as one that rolls, 50-130 degrees off
    # after 5 s), and such a run fits its measurements 2-8x worse than a sound one from its first 30-60 frames
    # on (docs/notes/visual-odometry.md). 1: one run.
    hypotheses: int = 3
    # Streaming (VisualOdometry, the vo node), the runs are compared after this many frames and only the best
    # goes on, so a long video costs one run's time and memory after them; shorter videos, and run_vo (whose
    # frames are all in memory anyway), compare the finished runs.
    hypotheses_frames: int = 300

    _PYTHON_FIELDS = ("hypotheses", "hypotheses_frames")  # settings of the Python side, not of the C++ core
    _LK_FIELDS = {"lk_window_px": "window_px", "lk_pyramid_levels": "pyramid_levels",
                  "forward_backward_px": "forward_backward_px", "reject_masked": "reject_masked",
                  "seed": "seed"}
    _SAMPLING_FIELDS = {"mask_dilation_px": "mask_dilation_px", "gradient_pool_px": "pool_px",
                        "min_gradient": "min_gradient"}

    def __post_init__(self):
        # The C++ core checks the patch-graph sizes; these would otherwise reach OpenCV or Ceres unchecked.
        check_settings(self, {"num_threads": 1, "max_image_side": 1, "lk_window_px": 1, "init_iterations": 0,
                              "window_iterations": 0, "final_iterations": 0, "hypotheses": 1,
                              "hypotheses_frames": 1},
                       ("keyframe_threshold_px", "new_keyframe_flow_px", "init_min_flow_px", "loss_scale_px",
                        "outlier_threshold_px", "forward_backward_px", "min_gradient"))

    def to_core(self) -> _core.PatchVOOptions:
        options = _core.PatchVOOptions()
        lk = options.lucas_kanade
        sampling = lk.sampling
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in self._PYTHON_FIELDS:
                continue
            if f.name in self._LK_FIELDS:
                setattr(lk, self._LK_FIELDS[f.name], value)
            elif f.name in self._SAMPLING_FIELDS:
                setattr(sampling, self._SAMPLING_FIELDS[f.name], value)
            else:
                setattr(options, f.name, value)
        lk.sampling = sampling
        options.lucas_kanade = lk
        return options


@dataclass
class VOResult:
    """Camera trajectory of every input frame.

    world_from_cam: (T, 4, 4) float64; world = the first camera (OpenCV axes: x right, y down, z forward);
        monocular, so the scale is arbitrary (median patch depth of the first keyframe = 1, or the depth
        maps').
    intrinsics: (4,) fx, fy, cx, cy at input resolution (given, or default_intrinsics).
    quality: per-frame arrays: attempted / tracked (front-end measurements), inliers (used by the final
        estimate, reprojection error < outlier threshold), reprojection_rms_px (processing resolution),
        keyframe, interpolated (skipped before initialisation, pose interpolated between keyframes),
        refined (non-keyframe pose refined motion-only against the final map).
    static_camera: the camera never moved enough to initialise; translation is zero, rotation fitted.
    stats: timings (seconds) and counts.
    points: (M, 3) float64, the final map in the world frame (VO units): every patch of a final keyframe
        that went through bundle adjustment with positive depth and >= 1 inlier measurement (empty for a
        static camera).
    point_frames: (M,) int host frame of each point; point_pixels: (M, 2) its pixel in the host frame
        (input resolution); point_inliers: (M,) inlier keyframe measurements of each point.
    """
    world_from_cam: np.ndarray
    intrinsics: np.ndarray
    quality: dict[str, np.ndarray]
    static_camera: bool
    stats: dict[str, float]
    message: str
    processing_scale: float = 1.0
    extra: dict = field(default_factory=dict)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    point_frames: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    point_pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point_inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))

    @property
    def camera_centres(self) -> np.ndarray:
        return self.world_from_cam[:, :3, 3]

    @property
    def tracking_ratio(self) -> np.ndarray:
        """Per-frame fraction of attempted measurements the front-end accepted (1 where none attempted)."""
        attempted = self.quality["attempted"].astype(np.float64)
        return np.where(attempted > 0, self.quality["tracked"] / np.maximum(attempted, 1), 1.0)

    @property
    def keyframe_fit_rms(self) -> float:
        """The reprojection rms (pixels, processing resolution) over every inlier measurement into the final
        keyframes: how well the final bundle adjustment explains the run's own measurements (the core's
        PatchVO::FitRms; inf without a map)."""
        return float(self.stats.get("keyframe_fit_rms_px", math.inf))

    @classmethod
    def from_core(cls, d: dict) -> "VOResult":
        return cls(world_from_cam=np.asarray(d["world_from_cam"]), intrinsics=np.asarray(d["intrinsics"]),
                   quality={k: np.asarray(v) for k, v in d["quality"].items()},
                   static_camera=bool(d["static_camera"]), stats=dict(d["stats"]), message=str(d["message"]),
                   processing_scale=float(d["processing_scale"]),
                   points=np.asarray(d.get("points", np.zeros((0, 3)))).reshape(-1, 3),
                   point_frames=np.asarray(d.get("point_frames", np.zeros(0, np.int32))),
                   point_pixels=np.asarray(d.get("point_pixels", np.zeros((0, 2)))).reshape(-1, 2),
                   point_inliers=np.asarray(d.get("point_inliers", np.zeros(0, np.int32))))


def _check_intrinsics(intrinsics) -> np.ndarray | None:
    if intrinsics is None:
        return None
    k = np.asarray(intrinsics, dtype=np.float64)
    if k.shape == (3, 3):
        k = np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])
    if k.shape != (4,):
        raise ValueError(
            f"intrinsics must be (4,) = (fx, fy, cx, cy) or a (3, 3) matrix, got shape {k.shape}")
    return k


def run_vo(frames: np.ndarray, masks: np.ndarray | None = None, depths: np.ndarray | None = None,
           intrinsics=None, config: VOConfig | None = None, bgr: bool = False) -> VOResult:
    """Patch visual odometry over a frame array.

    Args:
        frames: uint8 (T, H, W) gray or (T, H, W, 3) RGB (BGR with bgr=True).
        masks: None or bool (T, H, W), True on people (their gradient is zeroed so no patch is placed there,
            and measurements landing there are rejected).
        depths: None or float (T, H, W) per-pixel depth (any consistent unit) to initialise patch inverse
            depth.
        intrinsics: None, (fx, fy, cx, cy) or a 3x3 K, pixels of the input frames.
        config: VOConfig; its `hypotheses` runs (patch seeds seed, seed + 1, ...) go in parallel threads and the
            finished one of least keyframe_fit_rms is returned (with all frames in memory, the runs are compared
            at the end, whatever config.hypotheses_frames says).
    """
    frames = np.asarray(frames)
    if frames.dtype != np.uint8:
        raise ValueError(
            f"frames must be uint8, got {frames.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    config = config or VOConfig()
    k = _check_intrinsics(intrinsics)
    options = _hypothesis_options(config)
    with ThreadPoolExecutor(max_workers=min(len(options), _workers())) as pool:  # the core releases the GIL
        outs = list(pool.map(lambda o: _core.run_patch_vo(frames, masks, depths, k, o, bgr), options))
    return _best_fit([VOResult.from_core(out) for out in outs], [o.lucas_kanade.seed for o in options])


def _workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def _hypothesis_options(config: VOConfig) -> list:
    """The core's options of each run: config's, with patch-sampling seeds seed, seed + 1, ..."""
    options = []
    for k in range(config.hypotheses):
        o = config.to_core()
        lk = o.lucas_kanade
        lk.seed = config.seed + k
        o.lucas_kanade = lk
        options.append(o)
    return options


def _best_fit(results: list[VOResult], seeds: list[int]) -> VOResult:
    """The finished run of least keyframe_fit_rms (the first on ties), its message and stats saying so."""
    rms = [r.keyframe_fit_rms for r in results]
    best = _least(rms)
    return _note_choice(results[best], seeds, rms, best, None)


def _least(rms: list[float]) -> int:
    return min(range(len(rms)), key=lambda i: (rms[i], i))


def _note_choice(result: VOResult, seeds: list[int], rms: list[float], best: int, frames: int | None) -> VOResult:
    """`result` (run `best` of the runs with patch seeds `seeds` and fit `rms`, compared after `frames` frames or,
    None, finished) with the choice in its message and stats."""
    if len(seeds) == 1:
        return result
    others = ", ".join(f"{x:.2f}" for i, x in enumerate(rms) if i != best)
    when = f"after {frames} frames" if frames is not None else "finished"
    result.message += (f"; kept the best fit of {len(seeds)} runs {when} (patch seed {seeds[best]}: keyframe rms "
                       f"{rms[best]:.2f} px; the others {others})")
    result.stats.update(hypotheses=float(len(seeds)), hypothesis_kept=float(best),
                        hypotheses_compared_at=float(frames if frames is not None else result.stats["num_frames"]),
                        **{f"hypothesis_{i}_fit_rms_px": float(x) for i, x in enumerate(rms)})
    return result


class VisualOdometry:
    """Streaming interface: add frames one by one (e.g. while decoding a video), then finish(). Each frame goes to
    config.hypotheses runs at once (threads); after config.hypotheses_frames frames only the one of least
    keyframe reprojection rms goes on (in a shorter video finish() compares the finished runs, as run_vo does).

    front_end: None (Lucas-Kanade, in C++) or a Python front-end such as m3c.vo.dpvo.DPVOFrontEnd (DPVO's
    networks); one with push_image() also receives each colour frame (the C++ side passes it gray)."""

    def __init__(self, intrinsics=None, config: VOConfig | None = None, bgr: bool = False, front_end=None):
        config = config or VOConfig()
        self._front_end = front_end
        # A Python front-end keeps state per frame for one run: it gets one run, whatever config.hypotheses says.
        options = _hypothesis_options(config) if front_end is None else [config.to_core()]
        k = _check_intrinsics(intrinsics)
        self._runs = [_core.PatchVO(o, k, bgr, front_end) for o in options]
        self._seeds = [o.lucas_kanade.seed for o in options]
        self._pool = ThreadPoolExecutor(max_workers=min(len(options), _workers())) if len(options) > 1 else None
        self._compare_after = config.hypotheses_frames
        self._choice = None  # (seeds, rms, best, frames) once the runs were compared while streaming
        self._bgr = bgr

    def add_frame(self, frame: np.ndarray, mask: np.ndarray | None = None,
                  depth: np.ndarray | None = None) -> None:
        frame = np.asarray(frame)
        push = getattr(self._front_end, "push_image", None)
        if push is not None:
            colour = frame if frame.ndim == 3 else np.repeat(frame[..., None], 3, axis=2)
            push(colour if self._bgr or frame.ndim == 2 else colour[..., ::-1])  # BGR, as DPVO reads frames
        self._each(lambda vo: vo.add_frame(frame, mask, depth))
        if len(self._runs) > 1 and self._runs[0].num_frames >= self._compare_after:
            rms = [vo.fit_rms() for vo in self._runs]
            if not any(math.isfinite(x) for x in rms):
                return  # no map yet (the camera has not moved): compare later
            best = _least(rms)
            self._choice = (self._seeds, rms, best, self._runs[0].num_frames)
            self._runs, self._seeds = [self._runs[best]], [self._seeds[best]]  # the others' memory is freed
            self._pool.shutdown()
            self._pool = None

    @property
    def num_frames(self) -> int:
        return self._runs[0].num_frames

    def finish(self) -> VOResult:
        try:
            results = [VOResult.from_core(out) for out in self._each(lambda vo: vo.finish())]
        finally:
            if self._pool is not None:
                self._pool.shutdown()
        if self._choice is not None:
            return _note_choice(results[0], *self._choice)
        return _best_fit(results, self._seeds)

    def _each(self, call) -> list:
        """call(run) for every run, in parallel threads (the core releases the GIL)."""
        if self._pool is None:
            return [call(vo) for vo in self._runs]
        return list(self._pool.map(call, self._runs))
