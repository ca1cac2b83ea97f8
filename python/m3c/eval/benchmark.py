"""A ground-truth benchmark that runs offline: real motion capture, virtual cameras, simulated perception.

Each sequence places one to three people, whose motions are retargeted motion-capture clips (the CMU clips
shipped in m3c/eval/data, plus any BVH folder the user adds), in a world with a ground plane (y up, ground y
= 0, as m3c.eval.scenes). A virtual camera films them: walking handheld behind or beside the group, panning
from one spot, orbiting the group, or static on a tripod. From the ground truth the generator simulates what
the perception stages would give, with their typical errors:
  - COCO-17 keypoints: pixel noise that grows as the confidence drops, occlusion by nearer people (low
    confidence, large noise), points outside the image (confidence 0), outliers, dropped detections and
    occlusion gaps of several frames; a track spans its first to last detection;
  - camera-local bodies (what an HMR-style regressor gives per detection): root orientation errors (a slowly
    drifting bias plus jitter), depth errors along the viewing ray (a per-person bias plus jitter: the 2D
    projection stays right), body pose and shape errors; frames without a detection are infilled by
    interpolation (slerp for rotations), as the pipeline's local tracks are;
  - visual odometry: camera rotations with a random-walk drift, camera centres with a random-walk drift, and
    an unknown scale (VO units = metres / vo_scale); the VO world is gravity-aligned with the ground at y = 0;
  - foot contact probabilities with label flips.
Methods evaluated (thesis Table 5.1 rows):
  Local       the camera-local bodies placed in the world with the VO cameras at scale 1;
  Global Opt  m3c.motion.optimize (its default staged recipe) started from Local, with VPoser's pose prior
              when exported VPoser weights are configured (BenchmarkConfig.vposer);
  Global Regr and Global Regr + Opt need a world-lift regressor (WHAM weights); they are listed as not run.
Everything is seeded: the same config gives the same sequences and, up to the optimizer's floating-point
determinism, the same numbers.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.camera import UP, look_at, world_to_image
from m3c.eval import metrics as M
from m3c.eval.evaluate import aggregate, evaluate_sequence, format_method_table, format_value
from m3c.eval.retarget import RetargetedMotion
from m3c.eval.tracks import EvalTrack, body_eval_track
from m3c.motion import Cameras, OptimizerConfig, Track, optimize
from m3c.motion.interpolate import interpolate_rotations
from m3c.motion.scale import estimate_scale, rescaled
from m3c.nn import VPoser
from m3c.synth.cameras import ou_noise
from m3c.synth.people import true_contacts

CAMERA_MOTIONS = ("walking", "panning", "orbiting", "static")
METHODS = ("Local", "Global Regr", "Global Opt", "Global Regr + Opt")
NOT_RUN = {"Global Regr": "not run: needs a world-lift regressor (WHAM weights), none configured",
           "Global Regr + Opt": "not run: needs a world-lift regressor (WHAM weights), none configured"}
SHIPPED_CLIPS = ("cmu_131_01.npz", "cmu_01_01.npz")


@dataclass
class BenchmarkConfig:
    num_sequences: int = 2
    num_frames: int = 120
    seed: int = 0
    max_people: int = 3
    camera_motions: tuple = CAMERA_MOTIONS
    image_size: tuple = (1280, 720)        # pixels (W, H)
    focal_px: float = 1000.0                # about 65 degrees horizontal field of view at 1280 px
    # Keypoints
    keypoint_noise_px: float = 2.0          # at confidence 1; grows as 1 / confidence
    occluded_noise_px: float = 12.0
    outlier_rate: float = 0.01              # per keypoint: displaced by ~40 px with its confidence intact
    drop_rate: float = 0.05                 # per frame: the detector misses the person
    gaps_per_track: int = 1                 # occlusion gaps per person
    gap_frames: tuple = (5, 15)
    min_keypoints: int = 5                  # a detection needs this many visible keypoints
    # Camera-local bodies
    depth_bias: float = 0.12                # per person, relative, along the viewing ray
    depth_jitter: float = 0.015             # per frame, relative
    orientation_bias_deg: float = 6.0       # slowly drifting root orientation error (std)
    orientation_jitter_deg: float = 0.5     # per frame
    pose_bias: float = 0.09                 # rad per joint axis, per person
    pose_jitter: float = 0.012              # rad per joint axis, per frame
    shape_error: float = 0.4                # betas, per person
    contact_flip_rate: float = 0.05
    # Visual odometry
    vo_scale_range: tuple = (0.3, 3.0)      # metres per VO unit, log-uniform
    vo_rotation_drift_deg: float = 0.03     # random walk per frame
    vo_translation_drift: float = 0.003     # metres per frame, random walk
    # Where the motions come from
    clip_paths: tuple = ()                  # retargeted .npz files; empty: the shipped CMU clips
    optimizer: OptimizerConfig | None = None
    vposer: str = ""                        # exported vposer.safetensors enabling the optimizer's pose prior

    def validate(self) -> None:
        if self.num_sequences < 1 or self.num_frames < 10:
            raise ValueError("the benchmark needs at least 1 sequence of at least 10 frames")
        if not 1 <= self.max_people <= 3:
            raise ValueError(f"max_people must be 1, 2 or 3, got {self.max_people}")
        unknown = set(self.camera_motions) - set(CAMERA_MOTIONS)
        if unknown or not self.camera_motions:
            raise ValueError(f"camera motions must be among {CAMERA_MOTIONS}, got {list(self.camera_motions)}")


def shipped_clip_paths() -> list[Path]:
    base = resources.files("m3c.eval") / "data"
    paths = [Path(str(base / name)) for name in SHIPPED_CLIPS]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"the shipped benchmark motions are missing: {[str(p) for p in missing]}; "
                                "reinstall m3c or pass clip paths")
    return paths


def load_clips(paths=()) -> list[RetargetedMotion]:
    return [RetargetedMotion.load(p) for p in (paths or shipped_clip_paths())]


# Scene generation ------------------------------------------------------------------------------------------
@dataclass
class SimulatedTrack:
    """What the perception stages give for one person: detections over frames, camera-local bodies."""

    person: int                   # ground-truth index
    frames: np.ndarray            # (m,) the track's span, first to last detection
    detected: np.ndarray          # (m,) bool
    keypoints: np.ndarray         # (m, 17, 3) u, v, confidence (zeros where undetected)
    root_cam: np.ndarray          # (m, 3) camera-local estimates, infilled where undetected
    transl_cam: np.ndarray        # (m, 3)
    body_pose: np.ndarray         # (m, 23, 3)
    betas: np.ndarray             # (B,)
    contacts: np.ndarray          # (m, 4) probabilities for CONTACT_JOINTS


@dataclass
class BenchmarkSequence:
    name: str
    camera_motion: str
    fps: float
    truth: list[Track]            # full sequence, first_frame 0, world frame (metres)
    cameras_true: Cameras
    cameras_vo: Cameras
    vo_scale: float               # metres per VO unit
    simulated: list[SimulatedTrack]
    clips: list[str]

    def local_tracks(self, model: BodyModel) -> list[Track]:
        """The Local method: camera-local bodies placed with the VO cameras at scale 1 (the optimizer's
        start)."""
        out = []
        for sim in self.simulated:
            vo = self.cameras_vo.world_from_cam[sim.frames]
            root, transl = transform_smpl(vo, sim.root_cam, sim.transl_cam, rest_root_joint(model, sim.betas))
            # The ground as a camera-local estimate sees it (metric, in each frame's camera, as the optimizer
            # takes it): the world plane y = 0 in the true cameras.
            true = self.cameras_true.world_from_cam[sim.frames]
            normal_in_cam = np.einsum("tji,j->ti", true[:, :3, :3], UP)
            offset_in_cam = true[:, :3, 3] @ UP
            out.append(Track(int(sim.frames[0]), sim.keypoints.copy(), transl, root, sim.body_pose.copy(),
                             sim.betas.copy(), normal_in_cam, offset_in_cam, sim.contacts.copy()))
        return out


def _smooth(x: np.ndarray, window: int) -> np.ndarray:
    """Moving average along axis 0 with edge padding (same length)."""
    if window <= 1 or len(x) < 2:
        return x.copy()
    pad = window // 2
    padded = np.concatenate([np.repeat(x[:1], pad, 0), x, np.repeat(x[-1:], pad, 0)])
    kernel = np.ones(window) / window
    return np.stack([np.convolve(padded[:, k], kernel, mode="valid")[: len(x)] for k in range(x.shape[1])], 1)


def _place_people(model: BodyModel, clips: list[RetargetedMotion], count: int, n: int, rng):
    """Ground-truth tracks: clip segments turned and moved to spread-out starting spots on the ground."""
    usable = [c for c in clips if c.num_frames >= n]
    if not usable:
        raise ValueError(f"no motion clip has {n} frames (longest: {max(c.num_frames for c in clips)}); "
                         "ask for fewer frames or add longer clips")
    spots = []
    while len(spots) < count:
        p = rng.uniform(-1.5, 1.5, size=2)
        if np.hypot(*p) <= 1.5 and all(np.hypot(*(p - q)) >= 1.0 for q in spots):
            spots.append(p)
    truth, names = [], []
    for k in range(count):
        clip = usable[rng.integers(len(usable))]
        start = int(rng.integers(0, clip.num_frames - n + 1))
        seg = slice(start, start + n)
        betas = clip.betas + 0.3 * rng.normal(size=clip.betas.shape)
        root, transl, body = clip.root_orient[seg], clip.transl[seg], clip.body_pose[seg]
        pose0 = np.concatenate([root[:1, None], body[:1]], axis=1)
        pelvis0 = model.joints(pose0, betas, transl[:1])[0, 0]
        turn = Rotation.from_rotvec(rng.uniform(0, 2 * np.pi) * UP).as_matrix()
        T = np.eye(4)
        T[:3, :3] = turn
        T[[0, 2], 3] = spots[k] - (turn @ pelvis0)[[0, 2]]
        root, transl = transform_smpl(T, root, transl, rest_root_joint(model, betas))
        # The new shape changes leg length: stand on y = 0 again (as the retargeting did).
        pose = np.concatenate([root[:, None], body], axis=1)
        lowest = model.forward(pose, betas, transl).vertices[:, :, 1].min(axis=1)
        transl[:, 1] -= np.quantile(lowest, 0.1)
        contacts = true_contacts(model, pose, betas, transl)
        truth.append(Track(0, np.zeros((n, 17, 3)), transl, root, body.copy(), betas,
                           np.tile(UP, (n, 1)), np.zeros(n), contacts))
        names.append(f"{clip.info.get('name', 'clip')}@{start}")
    return truth, names


def _camera_path(motion: str, truth: list[Track], model: BodyModel, n: int, fps: float, config: BenchmarkConfig,
                 intrinsics: np.ndarray, rng) -> np.ndarray:
    """world_from_cam (n, 4, 4) for one of CAMERA_MOTIONS, aimed at the group."""
    pelvis = np.stack([model.joints(np.concatenate([t.root_orient[:, None], t.body_pose], 1), t.betas,
                                    t.transl)[:, 0] for t in truth])  # (P, n, 3)
    centre = _smooth(pelvis.mean(axis=0), int(fps) + 1)
    centre[:, 1] = 0.9
    t = np.arange(n) / fps
    phi0 = rng.uniform(0, 2 * np.pi)
    height = rng.uniform(1.4, 1.8)

    def ring(phi, dist):
        return np.stack([dist * np.sin(phi), np.full_like(phi, height - 0.9), dist * np.cos(phi)], axis=-1)

    shake = ou_noise(rng, n, 3, 0.005, 0.3 * fps)
    aim_shake = ou_noise(rng, n, 3, 0.02, 0.5 * fps)
    if motion == "walking":
        phi = phi0 + 0.15 * np.sin(2 * np.pi * t / max(t[-1], 1.0))
        bob = np.stack([0.015 * np.sin(2 * np.pi * 0.9 * t), 0.02 * np.sin(2 * np.pi * 1.8 * t), 0 * t], 1)
        eye = centre + ring(phi, rng.uniform(4.5, 5.5)) + bob + shake
        aim = centre + aim_shake
    elif motion == "panning":
        # From one spot, the operator follows the group and sweeps across it (about +-10 degrees).
        eye = np.repeat(centre[:1] + ring(np.array([phi0]), rng.uniform(5.0, 6.0)), n, 0) + 0.2 * shake
        across = np.array([np.cos(phi0), 0.0, -np.sin(phi0)])  # horizontal, perpendicular to the view
        sweep = np.sin(2 * np.pi * t / max(t[-1], 1.0) + rng.uniform(0, 2 * np.pi))
        aim = centre + aim_shake + sweep[:, None] * across
    elif motion == "orbiting":
        omega = rng.choice([-1.0, 1.0]) * rng.uniform(0.25, 0.5)
        eye = centre + ring(phi0 + omega * t, rng.uniform(4.5, 5.5)) + shake
        aim = centre + aim_shake
    elif motion == "static":
        middle = pelvis.reshape(-1, 3).mean(axis=0)
        middle[1] = 0.9
        W, H = config.image_size
        for dist in np.arange(5.0, 20.0, 0.5):  # back off until every pelvis stays in view with a margin
            eye0 = middle + ring(np.array([phi0]), dist)[0]
            uv, depth = world_to_image(pelvis.reshape(-1, 3), look_at(eye0, middle), intrinsics)
            if (depth > 0).all() and (np.abs(uv[:, 0] - W / 2) < 0.4 * W).all() and \
                    (np.abs(uv[:, 1] - H / 2) < 0.4 * H).all():
                break
        return np.repeat(look_at(eye0, middle)[None], n, 0)
    else:
        raise ValueError(f"unknown camera motion {motion!r}; choose from {CAMERA_MOTIONS}")
    return np.stack([look_at(e, a) for e, a in zip(eye, aim)])


def _simulate_keypoints(truth: list[Track], model: BodyModel, world_from_cam, intrinsics, config, rng):
    """Noisy COCO-17 detections (P, n, 17, 3) and a detected mask (P, n)."""
    W, H = config.image_size
    n = len(world_from_cam)
    regressor = model.coco17_regressor()
    uv, depth = [], []
    for tr in truth:
        pose = np.concatenate([tr.root_orient[:, None], tr.body_pose], axis=1)
        kp = model.keypoints(regressor, pose, tr.betas, tr.transl)
        proj = [world_to_image(kp[i], world_from_cam[i], intrinsics) for i in range(n)]
        uv.append(np.stack([p[0] for p in proj]))
        depth.append(np.stack([p[1] for p in proj]))
    uv, depth = np.stack(uv), np.stack(depth)  # (P, n, 17, 2), (P, n, 17)
    P = len(truth)
    conf = np.clip(rng.beta(6.0, 1.5, size=(P, n, 17)), 0.05, 1.0)
    noisy = uv + rng.normal(size=uv.shape) * (config.keypoint_noise_px / np.maximum(conf, 0.3))[..., None]
    inside = (depth > 0.1) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    # Occlusion by nearer people: a keypoint inside the (15 % enlarged) box of someone in front of it.
    for p in range(P):
        for q in range(P):
            if p == q:
                continue
            for i in range(n):
                seen = inside[q, i]
                if seen.sum() < 3:
                    continue
                lo, hi = uv[q, i, seen].min(0), uv[q, i, seen].max(0)
                pad = 0.075 * (hi - lo)
                in_box = ((uv[p, i] >= lo - pad) & (uv[p, i] <= hi + pad)).all(-1)
                behind = depth[p, i] > np.median(depth[q, i, seen]) + 0.2
                hidden = in_box & behind & inside[p, i]
                if hidden.any():
                    k = hidden.sum()
                    conf[p, i, hidden] *= rng.uniform(0.05, 0.35, size=k)
                    noisy[p, i, hidden] += config.occluded_noise_px * rng.normal(size=(k, 2))
    outliers = rng.uniform(size=(P, n, 17)) < config.outlier_rate
    noisy[outliers] += 40.0 * rng.normal(size=(outliers.sum(), 2))
    keypoints = np.concatenate([noisy, conf[..., None]], axis=-1)
    keypoints[~inside] = 0.0
    detected = (keypoints[..., 2] > 0).sum(-1) >= config.min_keypoints
    detected &= rng.uniform(size=(P, n)) >= config.drop_rate
    for p in range(P):
        for _ in range(config.gaps_per_track):
            length = int(rng.integers(config.gap_frames[0], config.gap_frames[1] + 1))
            start = int(rng.integers(0, max(1, n - length)))
            detected[p, start:start + length] = False
    keypoints[~detected] = 0.0
    return keypoints, detected


def _simulate_local(model, tr: Track, person: int, keypoints, detected, world_from_cam, config, fps, rng):
    """Camera-local estimates of one person over its span (None when it is never detected)."""
    hits = np.flatnonzero(detected)
    if len(hits) == 0:
        return None
    frames = np.arange(hits[0], hits[-1] + 1)
    m = len(frames)
    cam_from_world = np.linalg.inv(world_from_cam[frames])
    j0 = rest_root_joint(model, tr.betas)
    root_gt, transl_gt = transform_smpl(cam_from_world, tr.root_orient[frames], tr.transl[frames], j0)
    betas = tr.betas + config.shape_error * rng.normal(size=tr.betas.shape)
    # Depth error along the viewing ray of the pelvis: the projection stays right, the distance does not.
    factor = (1 + config.depth_bias * rng.normal()) * (1 + config.depth_jitter * rng.normal(size=m))
    pelvis = (transl_gt + j0) * factor[:, None]
    transl = pelvis - rest_root_joint(model, betas)
    tilt = np.radians(config.orientation_bias_deg) * ou_noise(rng, m, 3, 1.0, fps) / np.sqrt(3) + \
        np.radians(config.orientation_jitter_deg) * rng.normal(size=(m, 3)) / np.sqrt(3)
    root = (Rotation.from_rotvec(tilt) * Rotation.from_rotvec(root_gt)).as_rotvec()
    body = tr.body_pose[frames] + config.pose_bias * rng.normal(size=tr.body_pose.shape[1:]) + \
        config.pose_jitter * rng.normal(size=(m,) + tr.body_pose.shape[1:])
    # Infill frames without a detection from the detected ones (the pipeline's local tracks).
    seen = detected[frames]
    if not seen.all():
        kt, qt = np.flatnonzero(seen).astype(float), np.flatnonzero(~seen).astype(float)
        for d in range(3):
            transl[~seen, d] = np.interp(qt, kt, transl[seen, d])
        root[~seen] = interpolate_rotations(kt, root[seen][:, None], qt)[:, 0]
        body[~seen] = interpolate_rotations(kt, body[seen], qt)
    truth_contacts = tr.contacts[frames]
    prob = np.where(truth_contacts > 0.5, rng.uniform(0.7, 1.0, truth_contacts.shape),
                    rng.uniform(0.0, 0.3, truth_contacts.shape))
    flip = rng.uniform(size=prob.shape) < config.contact_flip_rate
    prob[flip] = 1.0 - prob[flip]
    return SimulatedTrack(person, frames, seen, keypoints[frames], root, transl, body, betas, prob)


def _visual_odometry(world_from_cam, static: bool, config, rng) -> tuple[np.ndarray, float]:
    n = len(world_from_cam)
    lo, hi = config.vo_scale_range
    vo_scale = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    vo = world_from_cam.copy()
    if not static:
        drift = np.cumsum(np.radians(config.vo_rotation_drift_deg) * rng.normal(size=(n, 3)), axis=0)
        drift -= drift[0]
        vo[:, :3, :3] = Rotation.from_rotvec(drift).as_matrix() @ world_from_cam[:, :3, :3]
        walk = np.cumsum(config.vo_translation_drift * rng.normal(size=(n, 3)), axis=0)
        vo[:, :3, 3] += walk - walk[0]
    vo[:, :3, 3] /= vo_scale
    return vo, vo_scale


def make_sequence(model: BodyModel, clips: list[RetargetedMotion], config: BenchmarkConfig, index: int,
                  fps: float = 30.0) -> BenchmarkSequence:
    """Sequence `index` of the benchmark (people 2, 3, 1, 2, ... up to max_people; camera motions in turn)."""
    rng = np.random.default_rng([config.seed, index])
    n = config.num_frames
    count = 1 + (index + 1) % config.max_people
    motion = config.camera_motions[index % len(config.camera_motions)]
    for clip in clips:
        if abs(clip.fps - fps) > 1e-3:
            raise ValueError(f"{clip.source}: clips must be at {fps:g} fps, this one is at {clip.fps:g}")
    truth, names = _place_people(model, clips, count, n, rng)
    W, H = config.image_size
    intrinsics = np.array([config.focal_px, config.focal_px, W / 2, H / 2])
    world_from_cam = _camera_path(motion, truth, model, n, fps, config, intrinsics, rng)
    static = motion == "static"
    vo, vo_scale = _visual_odometry(world_from_cam, static, config, rng)
    keypoints, detected = _simulate_keypoints(truth, model, world_from_cam, intrinsics, config, rng)
    simulated = []
    for p, tr in enumerate(truth):
        sim = _simulate_local(model, tr, p, keypoints[p], detected[p], world_from_cam, config, fps, rng)
        if sim is not None:
            simulated.append(sim)
    order = rng.permutation(len(simulated))  # tracker ids are not the dataset's: matching must find them
    simulated = [simulated[i] for i in order]
    name = f"seq{index:02d}_{motion}"
    return BenchmarkSequence(name, motion, fps, truth, Cameras(world_from_cam, intrinsics, static=static),
                             Cameras(vo, intrinsics, static=static), vo_scale, simulated, names)


# Running the methods ---------------------------------------------------------------------------------------
@dataclass
class SequenceReport:
    name: str
    camera_motion: str
    num_people: int
    clips: list
    vo_scale: float
    results: dict = field(default_factory=dict)     # method -> SequenceResult
    seconds: dict = field(default_factory=dict)     # method -> seconds
    camera: dict = field(default_factory=dict)      # method -> {"ate_mm", "rpe_mm", "rpe_deg", "scale_error_pct"}


def _eval_tracks(model, tracks: list[Track], world_from_cam) -> list[EvalTrack]:
    out = []
    for tr in tracks:
        frames = tr.first_frame + np.arange(tr.num_frames)
        out.append(body_eval_track(model, frames, tr.root_orient, tr.body_pose, tr.betas, tr.transl,
                                   world_from_cam[frames]))
    return out


def _camera_errors(pred_world_from_cam, true_world_from_cam, static: bool) -> dict:
    if static:
        return {}
    ate = M.camera_ate(pred_world_from_cam, true_world_from_cam)
    rpe_t, rpe_r = M.camera_rpe(pred_world_from_cam, true_world_from_cam)
    return {"ate_mm": float(np.sqrt((ate ** 2).mean())), "rpe_mm": float(rpe_t.mean()),
            "rpe_deg": float(rpe_r.mean())}


def run_sequence(model: BodyModel, seq: BenchmarkSequence, optimizer: OptimizerConfig | None = None,
                 log=None, pose_prior=None) -> SequenceReport:
    report = SequenceReport(seq.name, seq.camera_motion, len(seq.truth), seq.clips, seq.vo_scale)
    gt = _eval_tracks(model, seq.truth, seq.cameras_true.world_from_cam)
    static = seq.cameras_true.static

    start = time.perf_counter()
    local = seq.local_tracks(model)
    local_eval = _eval_tracks(model, local, seq.cameras_vo.world_from_cam)
    report.results["Local"] = evaluate_sequence(gt, local_eval, seq.fps, name=seq.name)
    report.seconds["Local"] = time.perf_counter() - start
    report.camera["Local"] = _camera_errors(seq.cameras_vo.world_from_cam, seq.cameras_true.world_from_cam, static)
    if log:
        log(f"{seq.name}: Local done ({report.seconds['Local']:.1f} s)")

    start = time.perf_counter()
    # As the pipeline: the scale estimator (its planted-feet source: the simulation has no map points), then the
    # optimizer from there.
    lifted, cameras = rescaled(local, seq.cameras_vo, estimate_scale(model, local, seq.cameras_vo))
    result = optimize(model, lifted, cameras, optimizer or OptimizerConfig.default(), pose_prior=pose_prior)
    cams = result.world_cameras(cameras).world_from_cam()
    opt_eval = _eval_tracks(model, result.tracks, cams)
    report.results["Global Opt"] = evaluate_sequence(gt, opt_eval, seq.fps, name=seq.name)
    report.seconds["Global Opt"] = time.perf_counter() - start
    camera = _camera_errors(cams, seq.cameras_true.world_from_cam, static)
    if not static:
        camera["scale_error_pct"] = float(100.0 * (result.camera_scale / seq.vo_scale - 1.0))
    report.camera["Global Opt"] = camera
    if log:
        log(f"{seq.name}: Global Opt done ({report.seconds['Global Opt']:.1f} s, camera scale "
            f"{result.camera_scale:.3f} vs true {seq.vo_scale:.3f})")
    return report


@dataclass
class BenchmarkReport:
    config: BenchmarkConfig
    sequences: list[SequenceReport]
    body_model: str

    def method_rows(self) -> dict:
        rows = {}
        for method in METHODS:
            if method in NOT_RUN:
                rows[method] = NOT_RUN[method]
                continue
            rows[method] = aggregate([s.results[method] for s in self.sequences if method in s.results])
        return rows

    def summary(self) -> dict:
        return {
            "config": {k: v for k, v in asdict(self.config).items() if k != "optimizer"},
            "body_model": self.body_model,
            "methods": self.method_rows(),
            "sequences": [{
                "name": s.name, "camera_motion": s.camera_motion, "people": s.num_people, "clips": s.clips,
                "vo_scale": s.vo_scale, "seconds": s.seconds, "camera": s.camera,
                "matched": {m: len(r.matching.matches) for m, r in s.results.items()},
                "metrics": {m: {k: r.mean(k) for k in r.values} for m, r in s.results.items()},
            } for s in self.sequences],
        }

    def tables(self) -> str:
        c = self.config
        lines = [f"M3C ground-truth benchmark: {len(self.sequences)} sequences x {c.num_frames} frames at 30 fps, "
                 f"seed {c.seed}; body model {self.body_model}, its 24 joints, pelvis = mean of the hips;",
                 "mm unless stated; means over all frames of all matched people.", "",
                 format_method_table(self.method_rows()), ""]
        run = [m for m in METHODS if m not in NOT_RUN]
        name_w = max(12, *(len(s.name) + 4 for s in self.sequences))
        cols = ("pa_mpjpe", "mpjpe", "w_mpjpe", "rte")
        head = "Sequence".ljust(name_w) + "".join(
            f"{m + ': PA-MPJPE':>22}{'MPJPE':>8}{'W-MPJPE':>9}{'RTE%':>7}" for m in run) + \
            f"{'ATE':>8}{'scale err%':>11}"
        lines += ["Per sequence (superscript: people; ATE of the Global Opt cameras after Sim(3), mm):", head,
                  "-" * len(head)]
        for s in self.sequences:
            row = f"{s.name}^{s.num_people}".ljust(name_w)
            for m in run:
                r = s.results[m]
                row += format_value(cols[0], r.mean(cols[0]), 22) + format_value(cols[1], r.mean(cols[1]), 8) + \
                    format_value(cols[2], r.mean(cols[2]), 9) + format_value(cols[3], r.mean(cols[3]), 7)
            cam = s.camera.get("Global Opt", {})
            row += (f"{cam['ate_mm']:8.1f}" if "ate_mm" in cam else f"{'-':>8}") + \
                (f"{cam['scale_error_pct']:11.1f}" if "scale_error_pct" in cam else f"{'-':>11}")
            lines.append(row)
        matched = sum(len(s.results["Global Opt"].matching.matches) for s in self.sequences)
        people = sum(s.num_people for s in self.sequences)
        seconds = {m: sum(s.seconds.get(m, 0.0) for s in self.sequences) for m in run}
        lines += ["", f"matched people: {matched}/{people}; time: " +
                  ", ".join(f"{m} {t:.1f} s" for m, t in seconds.items())]
        return "\n".join(lines)


def run_benchmark(model: BodyModel, config: BenchmarkConfig | None = None, log=None) -> BenchmarkReport:
    config = config or BenchmarkConfig()
    config.validate()
    clips = load_clips(config.clip_paths)
    pose_prior = VPoser(config.vposer) if config.vposer else None  # loaded once, shared by the sequences
    reports = []
    for index in range(config.num_sequences):
        seq = make_sequence(model, clips, config, index)
        if log:
            log(f"{seq.name}: {len(seq.truth)} people ({', '.join(seq.clips)}), {len(seq.simulated)} tracks, "
                f"VO scale {seq.vo_scale:.3f}")
        reports.append(run_sequence(model, seq, config.optimizer, log, pose_prior))
    return BenchmarkReport(config, reports, getattr(model.data, "name", ""))


# Motion from BVH folders ------------------------------------------------------------------------------------
def default_cache_dir() -> Path:
    import os

    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "m3c" / "mocap"


def retarget_folder(model: BodyModel, folder: str | Path, cache_dir: str | Path | None = None,
                    log=None) -> list[Path]:
    """Retargets every .bvh under `folder` at 30 fps (CMU files lose their added T-pose frame) into the cache
    (keyed by the file's bytes, the retarget settings and the body model) and returns the .npz paths."""
    import hashlib

    from m3c.eval.retarget import RetargetConfig, detect_joint_map, retarget
    from m3c.io.bvh import read_bvh

    folder = Path(folder)
    files = sorted(folder.rglob("*.bvh"))
    if not files:
        raise FileNotFoundError(f"no .bvh files under {folder}")
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    config = RetargetConfig()
    out = []
    for path in files:
        key = hashlib.sha1(path.read_bytes() + repr(config).encode() +
                           getattr(model.data, "name", "").encode()).hexdigest()[:12]
        target = cache / f"{path.stem}-{key}.npz"
        if not target.is_file():
            bvh = read_bvh(path)
            frames = slice(1, None) if detect_joint_map(bvh).startswith("cmu") else None
            start = time.perf_counter()
            motion = retarget(model, bvh, None, config, frames)
            motion.source = str(path)
            motion.save(target)
            if log:
                log(f"retargeted {path.name}: {motion.num_frames} frames, fit {motion.fit_error_mm.mean():.1f} mm "
                    f"({time.perf_counter() - start:.0f} s) -> {target}")
        out.append(target)
    return out
