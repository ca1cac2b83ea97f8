"""Public API of the patch visual odometry (the C++ core behind m3c._core.run_patch_vo / PatchVO)."""

from __future__ import annotations

import math
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

    _LK_FIELDS = {"lk_window_px": "window_px", "lk_pyramid_levels": "pyramid_levels",
                  "forward_backward_px": "forward_backward_px", "reject_masked": "reject_masked",
                  "seed": "seed"}
    _SAMPLING_FIELDS = {"mask_dilation_px": "mask_dilation_px", "gradient_pool_px": "pool_px",
                        "min_gradient": "min_gradient"}

    def __post_init__(self):
        # The C++ core checks the patch-graph sizes; these would otherwise reach OpenCV or Ceres unchecked.
        check_settings(self, {"num_threads": 1, "max_image_side": 1, "lk_window_px": 1, "init_iterations": 0,
                              "window_iterations": 0, "final_iterations": 0},
                       ("keyframe_threshold_px", "new_keyframe_flow_px", "init_min_flow_px", "loss_scale_px",
                        "outlier_threshold_px", "forward_backward_px", "min_gradient"))

    def to_core(self) -> _core.PatchVOOptions:
        options = _core.PatchVOOptions()
        lk = options.lucas_kanade
        sampling = lk.sampling
        for f in fields(self):
            value = getattr(self, f.name)
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
        config: VOConfig.
    """
    frames = np.asarray(frames)
    if frames.dtype != np.uint8:
        raise ValueError(
            f"frames must be uint8, got {frames.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    config = config or VOConfig()
    out = _core.run_patch_vo(frames, masks, depths, _check_intrinsics(intrinsics), config.to_core(), bgr)
    return VOResult.from_core(out)


class VisualOdometry:
    """Streaming interface: add frames one by one (e.g. while decoding a video), then finish().

    front_end: None (Lucas-Kanade, in C++) or a Python front-end such as m3c.vo.dpvo.DPVOFrontEnd (DPVO's
    networks); one with push_image() also receives each colour frame (the C++ side passes it gray)."""

    def __init__(self, intrinsics=None, config: VOConfig | None = None, bgr: bool = False, front_end=None):
        self._front_end = front_end
        self._vo = _core.PatchVO((config or VOConfig()).to_core(), _check_intrinsics(intrinsics), bgr, front_end)
        self._bgr = bgr

    def add_frame(self, frame: np.ndarray, mask: np.ndarray | None = None,
                  depth: np.ndarray | None = None) -> None:
        frame = np.asarray(frame)
        push = getattr(self._front_end, "push_image", None)
        if push is not None:
            colour = frame if frame.ndim == 3 else np.repeat(frame[..., None], 3, axis=2)
            push(colour if self._bgr or frame.ndim == 2 else colour[..., ::-1])  # BGR, as DPVO reads frames
        self._vo.add_frame(frame, mask, depth)

    @property
    def num_frames(self) -> int:
        return self._vo.num_frames

    def finish(self) -> VOResult:
        return VOResult.from_core(self._vo.finish())
