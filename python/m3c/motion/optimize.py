"""World-frame optimization of every person's motion: the public entry point over the C++ optimizer."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from m3c import _core
from m3c.body import BodyModel
from m3c.body.joint_names import CONTACT_JOINTS
from m3c.camera import WorldCameras
from m3c.motion.config import OptimizerConfig
from m3c.nn import HumorPrior, VPoser
from m3c.perception.contacts import contact_rest_heights



@dataclass
class Track:
    """One person over frames first_frame .. first_frame + n - 1, world frame, metres.

    keypoints: n x K x 3 (u, v, confidence; confidence 0 where unseen); transl: n x 3; root_orient: n x 3
    axis-angle; body_pose: n x (J-1) x 3; betas: B. Optional: ground_normal n x 3 and ground_offset n (the
    person's ground plane n.x + d = 0 in each frame's CAMERA coordinates, metric, as a camera-local estimate
    gives it: it moves with the camera scale the optimizer estimates), contacts n x 4 probabilities for
    CONTACT_JOINTS (planted: contact_velocity holds them still), ground_contacts n x 4 (those surely on the ground,
    which contact_height pulls onto it, each joint to its height above the sole in the rest pose at the track's
    betas, m3c.perception.contacts.contact_rest_heights; None: contacts).
    """

    first_frame: int
    keypoints: np.ndarray
    transl: np.ndarray
    root_orient: np.ndarray
    body_pose: np.ndarray
    betas: np.ndarray
    ground_normal: np.ndarray | None = None
    ground_offset: np.ndarray | None = None
    contacts: np.ndarray | None = None
    ground_contacts: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return len(self.transl)


@dataclass
class Cameras:
    """The optimizer's cameras. world_from_cam: T x 4 x 4 (world axes, translation in VO units: the camera centre is
    scale * translation + offset, the scale and offset being the optimizer's unknowns); intrinsics: T x 4 or 4 (fx,
    fy, cx, cy). initial_scale: the metric size of one VO unit to start from (m3c.vo.scale's estimate; refined by
    stages that free the scale, unless static); scale_sigma: its uncertainty, the standard deviation of
    log(initial_scale) (the "scale_prior" term; None: no prior). times: (T,) each frame's time in seconds when the
    frame rate varies (the smoothness and contact stencils are then finite differences at these times); None:
    equally spaced."""

    world_from_cam: np.ndarray
    intrinsics: np.ndarray
    static: bool = False
    initial_scale: float = 1.0
    scale_sigma: float | None = None
    times: np.ndarray | None = None

    @classmethod
    def from_world(cls, cameras: WorldCameras, intrinsics: np.ndarray, **kwargs) -> Cameras:
        """The optimizer's cameras starting at the pipeline's `cameras` (one scale, no offset: the optimizer's
        offset starts at 0); kwargs: static, scale_sigma, times."""
        if np.ndim(cameras.scale) or np.any(cameras.offset):
            raise ValueError("the optimizer starts from cameras with one scale and no offset (the lift's), got "
                             f"scale of shape {np.shape(cameras.scale)} and offset {np.asarray(cameras.offset)[:3]}")
        return cls(cameras.world_from_cam_vo(), intrinsics, initial_scale=float(cameras.scale), **kwargs)


@dataclass
class StageResult:
    name: str
    status: str
    message: str
    iterations: int
    seconds: float
    objective_before: float
    objective_after: float
    camera_scale: float  # after the stage
    world_before: float  # the world check (OptimizerConfig.world_check) before and after the stage
    world_after: float
    terms: dict  # term -> (before, after)
    # Problems the stage was solved as: one per person where they share no free parameter (the camera scale
    # held), solved side by side; iterations is then the most any of them took.
    parts: int = 1


@dataclass
class WorldResult:
    tracks: list[Track]
    camera_scale: float
    camera_offset: np.ndarray
    stages: list[StageResult]
    stopped_early: bool
    # Per track, the (n, 32) VPoser latents the body pose was optimised as (config.latent_pose with VPoser
    # weights); None otherwise. body_pose[:, :21] is their decoding.
    latent_poses: list = field(default_factory=list)

    def world_cameras(self, cameras: Cameras) -> WorldCameras:
        """The optimised cameras: the input `cameras` at the recovered scale and offset."""
        return WorldCameras.from_vo(cameras.world_from_cam, self.camera_scale, offset=self.camera_offset)


def _matrix(value, rows: int, cols: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.size != rows * cols:
        raise ValueError(f"{name} must have {rows} x {cols} values, got shape {arr.shape}")
    return np.ascontiguousarray(arr.reshape(rows, cols))


def _to_core_track(track: Track, model: BodyModel, num_keypoints: int) -> "_core.TrackInput":
    n, J = track.num_frames, model.num_joints
    core = _core.TrackInput()
    core.first_frame = int(track.first_frame)
    core.keypoints = _matrix(track.keypoints, n, 3 * num_keypoints, "keypoints")
    core.transl = _matrix(track.transl, n, 3, "transl")
    core.root = _matrix(track.root_orient, n, 3, "root_orient")
    core.body = _matrix(track.body_pose, n, 3 * (J - 1), "body_pose")
    core.betas = np.asarray(track.betas, dtype=np.float64).reshape(-1)
    if track.ground_normal is not None:
        core.ground_normal = _matrix(track.ground_normal, n, 3, "ground_normal")
        core.ground_offset = np.asarray(track.ground_offset, dtype=np.float64).reshape(-1)
    if track.ground_contacts is not None and track.contacts is None:
        raise ValueError("ground_contacts are given without contacts: give the planted feet's contacts too")
    if track.contacts is not None:
        core.contacts = _matrix(track.contacts, n, len(CONTACT_JOINTS), "contacts")
        if track.ground_contacts is not None:
            core.ground_contacts = _matrix(track.ground_contacts, n, len(CONTACT_JOINTS), "ground_contacts")
    core.contact_heights = contact_rest_heights(model, core.betas)
    return core


def optimize(model: BodyModel, tracks: list[Track], cameras: Cameras, config: OptimizerConfig | None = None,
             keypoint_regressor=None, motion_prior=None, fps: float = 30.0, pose_prior=None) -> WorldResult:
    """Optimises every track in the world frame with the staged recipe of `config` (default: the thesis's).

    keypoint_regressor: the body's keypoints that `Track.keypoints` observe (default COCO-17).
    motion_prior: a HuMoR prior (m3c.nn.HumorPrior, or the path of an exported humor.safetensors, see
    `python -m m3c.models.export`) enabling the "motion_prior" term; fps: the video's frame rate.
    pose_prior: a VPoser (m3c.nn.VPoser, or the path of an exported vposer.safetensors) enabling the
    "pose_prior" and "latent_smoothness" terms; without it they are reported unavailable and the body pose is
    held by "pose_anchor" (a Gaussian around the initial pose).
    """
    config = config or OptimizerConfig.default()
    regressor = keypoint_regressor or model.coco17_regressor()
    K = regressor.num_keypoints
    world_from_cam = np.asarray(cameras.world_from_cam, dtype=np.float64)
    if world_from_cam.ndim != 3 or world_from_cam.shape[1:] != (4, 4):
        raise ValueError(f"world_from_cam must have shape (T, 4, 4), got {world_from_cam.shape}")
    T = len(world_from_cam)
    intrinsics = np.asarray(cameras.intrinsics, dtype=np.float64)
    if intrinsics.shape == (4,):
        intrinsics = np.tile(intrinsics, (T, 1))
    if intrinsics.shape != (T, 4):
        raise ValueError(f"intrinsics must have shape (4,) or (T={T}, 4), got {intrinsics.shape}")
    core_cams = _core.CameraInput()
    core_cams.world_from_cam = list(world_from_cam)
    core_cams.intrinsics = intrinsics
    core_cams.static_camera = bool(cameras.static)
    core_cams.initial_scale = float(cameras.initial_scale)
    core_cams.scale_sigma = float(cameras.scale_sigma) if cameras.scale_sigma is not None else 0.0
    if cameras.times is not None:
        times = np.asarray(cameras.times, dtype=np.float64)
        if times.shape != (T,) or not np.isfinite(times).all() or (np.diff(times) <= 0).any():
            raise ValueError(f"times must be T={T} finite, increasing frame times in seconds, got shape {times.shape}")
        core_cams.times = list(times)
    jw = np.zeros((len(CONTACT_JOINTS), model.num_joints))  # the contact points: CONTACT_JOINTS
    jw[np.arange(len(CONTACT_JOINTS)), list(CONTACT_JOINTS)] = 1.0
    contact_regressor = model.regressor(joint_weights=jw)
    core_tracks = [_to_core_track(t, model, K) for t in tracks]
    if motion_prior is not None and not isinstance(motion_prior, HumorPrior):
        motion_prior = HumorPrior(motion_prior)
    if pose_prior is not None and not isinstance(pose_prior, VPoser):
        pose_prior = VPoser(pose_prior)
    prior_core = motion_prior._core if motion_prior is not None else None
    vposer_core = pose_prior._core if pose_prior is not None else None
    result = _core.optimize_world(model._core, regressor, contact_regressor, core_tracks, core_cams, config.to_core(),
                                  prior_core, float(fps), vposer_core)

    out_tracks = []
    for track, res in zip(tracks, result.tracks):
        n = track.num_frames
        out_tracks.append(replace(track, keypoints=np.asarray(track.keypoints), transl=res.transl.copy(),
                                  root_orient=res.root.copy(), body_pose=res.body.reshape(n, -1, 3).copy(),
                                  betas=res.betas.copy()))
    stages = [StageResult(s.name, s.status, s.message, s.iterations, s.seconds, s.objective_before,
                          s.objective_after, s.scale, s.world_before, s.world_after,
                          {t.term: (t.before, t.after) for t in s.terms}, s.parts)
              for s in result.stages]
    latents = [res.latent.copy() if res.latent.size else None for res in result.tracks]
    return WorldResult(out_tracks, float(result.scale), np.asarray(result.offset), stages, bool(result.stopped_early),
                       latents)


def track_joints(model: BodyModel, track: Track) -> np.ndarray:
    """World-frame joints n x J x 3 of a track."""
    pose = np.concatenate([np.asarray(track.root_orient).reshape(-1, 1, 3),
                           np.asarray(track.body_pose).reshape(track.num_frames, -1, 3)], axis=1)
    return model.joints(pose, np.asarray(track.betas, dtype=np.float64), np.asarray(track.transl))
