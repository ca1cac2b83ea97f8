"""Training M3C's own world regressor: WHAM's layout (m3c.models.wham: motion encoder, trajectory decoder,
motion decoder, under the official module names, at width `width` instead of 512; no image features, no
integrator, no refiner) on a motion-capture corpus of `m3c data mocap` seen through virtual cameras
(m3c.training.virtual_camera), as WHAM itself is trained.

A sample is a window of `frames` frames of a training clip (turned about the vertical by a random angle), a
random virtual camera, the clip's COCO-17 keypoints projected and corrupted by the measured detector errors.
The network reads WHAM's inputs (m3c.models.wham.keypoint_inputs; the camera's angular velocity; the previous
frame's root orientation in WHAM's y-down world, 3D keypoints and camera-frame pose as its initial state, the
last two perturbed) and predicts, per frame, root-centred camera-frame 3D keypoints, the world root
orientation and velocity (in the previous root frame), the camera-frame pose (24 x 6D), betas and foot
contacts. Loss:
    kp_weight |K - K*|^2 + |R_pose - R_pose*|_F^2 + joint_weight |J - J*|^2 + |R_root - R_root*|_F^2
    + |fps (v - v*)|^2 + betas_weight |b - b*|^2 + contact_weight BCE(c, c*)
(means over frames and joints; J the 24 joints of the camera-frame pose at zero betas, metres). AdamW, cosine
decay; each batch is drawn from a generator seeded by (seed, step), so `--resume` continues a run exactly.

Root orientation (config.root, saved in regressor.pt as `formulation`): "absolute" is WHAM's reading of the
trajectory decoder's 6D, the world orientation itself; "residual" (the default) reads it as a change from the
previous frame's orientation, R[t] = R[t-1] C[t] (m3c.models.wham.compose_root), the head zero at
initialisation so that an untrained network holds the initial orientation. C[t] is the body's turn in its own
frame, which the camera-frame keypoints and the camera's rotation determine; the absolute orientation is not
determined by them (the world heading enters only through the initial state), so fed back it compounds.

Exposure bias (sampling_passes K > 0, parallel scheduled sampling): before the step's teacher-forced pass, K
passes without gradients each feed the decoders the previous pass's own outputs as their previous-frame
values (each frame with probability p, else the noisy truth; p ramps linearly from 0 to sampling_prob over
the first half of the steps). With p = 1 the K-th pass is the autoregressive network on the first K + 1
frames, so the decoders see their own errors compounded over up to K frames, at K forward passes a step.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial.transform import Rotation

from m3c.io.atomic import atomic_path
from m3c.models import wham
from m3c.models.rotations import matrix_to_rotation_6d_rows, rotation_6d_to_matrix_rows
from m3c.training.common import JointKinematics, ResumableRun, save_checkpoint, seed_everything
from m3c.training.virtual_camera import DetectorErrors, VirtualCameraConfig, project_keypoints, sample_camera

FLIP = np.diag([1.0, -1.0, -1.0])  # M3C's y-up world -> WHAM's y-down one (m3c.motion.wham_lift.FLIP)
ROOT_FORMULATIONS = ("residual", "absolute")


@dataclass
class RegressorConfig:
    steps: int = 20000
    batch_size: int = 32
    frames: int = 48                  # window length
    width: int = 128                  # WHAM's: 512
    lr: float = 1e-3
    weight_decay: float = 1e-5
    kp_weight: float = 10.0
    joint_weight: float = 10.0
    betas_weight: float = 0.1
    contact_weight: float = 0.1
    dropout: float = 0.3              # WHAM's, between the LSTM layers (and half of it on the input embedding)
    init_pose_noise: float = 0.15     # rad, per joint, on the initial camera-frame pose
    init_kp_noise: float = 0.02       # m, on the initial 3D keypoints
    teacher_noise: float = 0.05       # teacher-forced previous 6D values (a fifth of it, in m, on keypoints)
    root_noise: float | None = None   # the same on the previous root orientation (None: teacher_noise). The
    # residual root is composed on that noisy previous one, so the head learns to undo noise it cannot see
    # (the heading): at 0.2 it erred more than holding (full corpus, 2400 steps: 16.5 deg against 13.8).
    root: str = "residual"            # ROOT_FORMULATIONS: how the trajectory decoder's 6D is read
    sampling_passes: int = 0          # passes of parallel scheduled sampling before each step (0: off)
    sampling_prob: float = 0.5        # their final share of frames fed the network's own previous values
    seed: int = 0
    checkpoint_minutes: float = 3.0
    history_every: int = 50
    camera: VirtualCameraConfig = field(default_factory=VirtualCameraConfig)


def config_from_dict(values: dict) -> RegressorConfig:
    """A RegressorConfig back from its asdict() (train.json's "config"), the virtual camera's included."""
    values = dict(values)
    camera = VirtualCameraConfig(**{k: tuple(v) if isinstance(v, list) else v
                                    for k, v in values.pop("camera", {}).items()})
    return RegressorConfig(**values, camera=camera)


class WorldRegressor(wham.WhamLifter):
    """WhamLifter's motion encoder, trajectory decoder and motion decoder at width `width` (context width +
    51), under WHAM's module names: its state dict is a subset of an official checkpoint's layout (width 512
    would load one's modules). root: how the trajectory decoder's orientation head is read (the module
    docstring); "residual" starts with the head at zero, i.e. holding the initial orientation."""

    def __init__(self, width: int = 128, root: str = "residual", dropout: float = 0.3):
        torch.nn.Module.__init__(self)
        if root not in ROOT_FORMULATIONS:
            raise ValueError(f"unknown root formulation {root!r}; choose from {ROOT_FORMULATIONS}")
        self.width, self.root = width, root
        context = width + 3 * wham.NUM_KEYPOINTS
        self.mask_embedding = torch.nn.Parameter(torch.zeros(1, 1, wham.NUM_KEYPOINTS, 2))
        self.motion_encoder = wham.MotionEncoder(d_embed=width)
        self.trajectory_decoder = wham.TrajectoryDecoder(d_context=context)
        self.motion_decoder = wham.MotionDecoder(d_context=context)
        self.set_dropout(dropout)
        if root == "residual":
            self.trajectory_decoder.residual = True     # an instance flag: WHAM's class keeps its reading
            head = self.trajectory_decoder.regressor.declayer1
            torch.nn.init.zeros_(head.weight)
            torch.nn.init.zeros_(head.bias)

    def set_dropout(self, p: float) -> None:
        """Dropout p between the LSTM layers of the three modules and p / 2 on the encoder's input embedding
        (WHAM's: 0.3 and 0.15); only training sees it, and the state dict does not hold it."""
        if not 0.0 <= p < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {p}")
        self.motion_encoder.pos_drop.p = p / 2
        for module in (self.motion_encoder, self.trajectory_decoder, self.motion_decoder):
            module.regressor.rnn.dropout = p

    def forward(self, x, mask, init_kp, init_root, cam_angvel, init_pose) -> dict:
        """lift()'s outputs (see WhamLifter.lift) and the motion decoder's: pose (B, F, 24, 6), betas (B, F,
        10), contact logits (B, F, 4)."""
        out = self.lift(x, mask, init_kp, init_root, cam_angvel)
        pose, betas, _, contact = self.motion_decoder(out["context"], init_pose)
        return dict(out, pose=pose.reshape(*pose.shape[:2], 24, 6), betas=betas, contact=contact)

    def teacher_forced(self, x, mask, init_kp, init_root, cam_angvel, init_pose, previous: dict) -> dict:
        """forward()'s outputs with each decoder fed the given previous-frame values instead of its own
        (teacher forcing: each LSTM then runs over the whole window in one call). previous: keypoints_3d
        (B, F, 51), root_6d (B, F, 6), pose (B, F, 144), each frame's value for the frame before it."""
        encoder = self.motion_encoder
        h = encoder.pos_drop(encoder.embed_layer(self.masked_input(x, mask)))
        (keypoints,), h, _ = encoder.regressor(h, [previous["keypoints_3d"]], encoder.neural_init(init_kp))
        context = torch.cat([h, keypoints], dim=-1)
        (velocity, root), _, _ = self.trajectory_decoder.regressor(context, [previous["root_6d"], cam_angvel])
        if self.root == "residual":
            root = wham.compose_root(previous["root_6d"], root)
        decoder = self.motion_decoder
        b = context.shape[0]
        state = decoder.neural_init(init_pose[:, :, list(wham.MAIN_JOINTS)].reshape(b, 1, -1))
        (pose, betas, _, contact), _, _ = decoder.regressor(context, [previous["pose"]], state)
        return {"keypoints_3d": keypoints.reshape(b, -1, wham.NUM_KEYPOINTS, 3), "context": context,
                "root_6d": torch.cat([init_root, root], dim=1), "velocity": velocity,
                "pose": pose.reshape(b, -1, 24, 6), "betas": betas, "contact": contact}


# Data -------------------------------------------------------------------------------------------------------
def prepare_clips(clips, model, frames: int) -> list[dict]:
    """Per clip of at least frames + 1 frames: world joints (T, 24, 3), COCO-17 keypoints (T, 17, 3), root and
    body rotations (T, 24, 3, 3), betas, contacts (T, 4), fps."""
    regressor = model.coco17_regressor()
    out = []
    for clip in clips:
        pose = np.asarray(clip["pose"], dtype=np.float64)
        if len(pose) < frames + 1:
            continue
        betas = np.asarray(clip["betas"], dtype=np.float64)
        transl = np.asarray(clip["transl"], dtype=np.float64)
        out.append({"joints": model.joints(pose, betas, transl),
                    "coco": model.keypoints(regressor, pose, betas, transl),
                    "rot": Rotation.from_rotvec(pose.reshape(-1, 3)).as_matrix().reshape(len(pose), 24, 3, 3),
                    "betas": betas[:10], "contacts": np.asarray(clip["contacts"], dtype=np.float64),
                    "fps": float(clip["fps"])})
    if not out:
        raise ValueError(f"no clip of at least {frames + 1} frames to draw windows from")
    return out


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def sample_window(rng: np.random.Generator, clips: list[dict], config: RegressorConfig,
                  errors: DetectorErrors) -> dict:
    """One training sample (numpy, float64) from a random window of a random clip (by length) and camera."""
    lengths = np.array([len(c["joints"]) - config.frames for c in clips], dtype=np.float64)
    clip = clips[rng.choice(len(clips), p=lengths / lengths.sum())]
    n = config.frames
    s = int(rng.integers(1, len(clip["joints"]) - n + 1))
    win = slice(s - 1, s + n)                                    # the previous frame and the window
    turn = _yaw(rng.uniform(0, 2 * np.pi))
    joints, coco = clip["joints"][win] @ turn.T, clip["coco"][win] @ turn.T
    root = turn @ clip["rot"][win, 0]
    camera = sample_camera(rng, joints[1:, 0], clip["fps"], config.camera)
    pixels, depth = project_keypoints(coco[1:], camera["world_from_cam"], camera["intrinsics"])
    det = errors.corrupt(rng, pixels, depth, camera["image_size"], config.camera)
    x, mask = wham.keypoint_inputs(det["keypoints"], det["confidence"], det["box"], camera["image_size"])
    cam_from_world = np.transpose(camera["world_from_cam"][:, :3, :3], (0, 2, 1))   # (n, 3, 3), M3C world
    # The previous frame's camera: the window's first (the decoder's initial state is in its frame).
    cams = np.concatenate([cam_from_world[:1], cam_from_world])
    centres = np.concatenate([camera["world_from_cam"][:1, :3, 3], camera["world_from_cam"][:, :3, 3]])
    coco_cam = np.einsum("nij,nkj->nki", cams, coco - centres[:, None])
    kp3d = coco_cam - coco_cam[:, [11, 12]].mean(1, keepdims=True)
    pose_cam = clip["rot"][win].copy()
    pose_cam[:, 0] = cams @ root
    root_wham = FLIP @ root                                      # (n + 1, 3, 3) y-down world
    pelvis = joints[:, 0] @ FLIP                                 # FLIP is symmetric
    velocity = np.einsum("nji,nj->ni", root_wham[:-1], pelvis[1:] - pelvis[:-1])
    init_pose = Rotation.from_matrix(pose_cam[0]).as_rotvec() + config.init_pose_noise * rng.standard_normal(
        (24, 3))
    init_kp = kp3d[0] + config.init_kp_noise * rng.standard_normal((17, 3))
    wham_cam_from_world = np.transpose(FLIP @ camera["world_from_cam"][:, :3, :3], (0, 2, 1))
    angvel = wham.camera_angular_velocity(torch.as_tensor(wham_cam_from_world), clip["fps"]).numpy()
    return {"x": x.numpy(), "mask": mask.numpy(),
            "init_kp": np.concatenate([init_kp.reshape(-1), x[0].numpy()]), "init_root": root_wham[0],
            "angvel": angvel, "init_pose": Rotation.from_rotvec(init_pose).as_matrix(),
            "kp3d": kp3d[1:], "root": root_wham[1:], "velocity": velocity, "pose": pose_cam[1:],
            "betas": clip["betas"], "contacts": clip["contacts"][s:s + n], "fps": clip["fps"],
            "visible": det["confidence"].mean()}


def make_batch(rng: np.random.Generator, clips, config: RegressorConfig, errors: DetectorErrors,
               size: int | None = None) -> dict:
    """A batch of sample_window samples as float32 tensors (the 6D of rotations in WHAM's row layout)."""
    samples = [sample_window(rng, clips, config, errors) for _ in range(size or config.batch_size)]
    batch = {k: torch.as_tensor(np.stack([s[k] for s in samples])) for k in samples[0]}
    out = {k: v.float() for k, v in batch.items() if k != "mask"}
    out["mask"] = batch["mask"].bool()
    out["init_kp"] = out["init_kp"][:, None]
    out["init_root"] = matrix_to_rotation_6d_rows(out["init_root"])[:, None]
    out["init_pose"] = matrix_to_rotation_6d_rows(out["init_pose"])[:, None]
    return out


def run_network(net: WorldRegressor, batch: dict) -> dict:
    """The network as it runs at inference: autoregressive."""
    return net(batch["x"], batch["mask"], batch["init_kp"], batch["init_root"], batch["angvel"],
               batch["init_pose"])


def own_previous(batch: dict, out: dict) -> dict:
    """teacher_forced()'s `previous` from the network's own outputs: each frame gets the output of the frame
    before it (the first frame: the batch's initial state)."""
    b, f = batch["x"].shape[:2]
    kp, pose = out["keypoints_3d"].reshape(b, f, -1), out["pose"].reshape(b, f, -1)
    return {"keypoints_3d": torch.cat([batch["init_kp"][..., :3 * wham.NUM_KEYPOINTS], kp[:, :-1]], 1),
            "root_6d": out["root_6d"][:, :-1],
            "pose": torch.cat([batch["init_pose"].reshape(b, 1, -1), pose[:, :-1]], 1)}


def run_teacher_forced(net: WorldRegressor, batch: dict, noise: float, passes: int = 0,
                       prob: float = 0.0, root_noise: float | None = None) -> dict:
    """The network fed the true previous-frame values, perturbed by Gaussian noise: `noise` on the 6D
    rotations, noise / 5 metres on the 3D keypoints (the first frame's: the initial state the batch gives).
    passes > 0: parallel scheduled sampling (the module docstring), each frame fed the previous pass's own
    outputs with probability prob; the sampling passes carry no gradient."""
    b, f = batch["x"].shape[:2]

    def shifted(first, rest, scale):
        values = torch.cat([first, rest[:, :-1]], dim=1)
        return values + scale * torch.randn_like(values)

    previous = {"keypoints_3d": shifted(batch["init_kp"][..., :3 * wham.NUM_KEYPOINTS],
                                        batch["kp3d"].reshape(b, f, -1), noise / 5),
                "root_6d": shifted(batch["init_root"], matrix_to_rotation_6d_rows(batch["root"]),
                                   noise if root_noise is None else root_noise),
                "pose": shifted(batch["init_pose"].reshape(b, 1, -1),
                                matrix_to_rotation_6d_rows(batch["pose"]).reshape(b, f, -1), noise)}
    inputs = (batch["x"], batch["mask"], batch["init_kp"], batch["init_root"], batch["angvel"],
              batch["init_pose"])
    if passes > 0:
        # One draw per frame for all three decoders; the first frame's previous is the initial state anyway.
        own = (torch.rand(b, f, 1) < prob).float()
        truth, mixed = previous, previous
        for _ in range(passes):
            with torch.no_grad():
                sampled = own_previous(batch, net.teacher_forced(*inputs, mixed))
            mixed = {k: own * sampled[k] + (1 - own) * truth[k] for k in truth}
        previous = mixed
    return net.teacher_forced(*inputs, previous)


def sampling_prob(config: RegressorConfig, step: int) -> float:
    """The scheduled share of own previous values at `step`: 0 -> config.sampling_prob over half the run."""
    return config.sampling_prob * min(1.0, step / max(config.steps / 2, 1.0))


class RegressorLoss(torch.nn.Module):
    def __init__(self, kinematics: JointKinematics, config: RegressorConfig):
        super().__init__()
        self.kin, self.config = kinematics, config

    def joints(self, rot: torch.Tensor) -> torch.Tensor:
        """(B, F, 24, 3, 3) camera-frame pose -> (B, F, 24, 3) joints about the root."""
        b, f = rot.shape[:2]
        return self.kin(rot.reshape(b * f, 24, 3, 3)).reshape(b, f, 24, 3)

    def forward(self, out: dict, batch: dict) -> dict:
        c = self.config
        pose = rotation_6d_to_matrix_rows(out["pose"])
        root = rotation_6d_to_matrix_rows(out["root_6d"][:, 1:])
        terms = {
            "kp3d": ((out["keypoints_3d"] - batch["kp3d"]) ** 2).sum(-1).mean(),
            "pose": ((pose - batch["pose"]) ** 2).sum((-1, -2)).mean(),
            "joints": ((self.joints(pose) - self.joints(batch["pose"])) ** 2).sum(-1).mean(),
            "root": ((root - batch["root"]) ** 2).sum((-1, -2)).mean(),
            "velocity": (((out["velocity"] - batch["velocity"]) * batch["fps"][:, None, None]) ** 2)
            .sum(-1).mean(),
            "betas": ((out["betas"] - batch["betas"][:, None]) ** 2).mean(),
            "contact": F.binary_cross_entropy_with_logits(out["contact"], batch["contacts"]),
        }
        terms["loss"] = (c.kp_weight * terms["kp3d"] + terms["pose"] + c.joint_weight * terms["joints"]
                         + terms["root"] + terms["velocity"] + c.betas_weight * terms["betas"]
                         + c.contact_weight * terms["contact"])
        return terms


def batch_rng(seed: int, step: int) -> np.random.Generator:
    """The generator of the batch of `step`: seeded by (seed, step) alone, so a resumed run draws what the
    uninterrupted one would."""
    return np.random.default_rng([seed, step, 60])


def train_regressor(clips: list[dict], out_dir: str | Path, body_model, config: RegressorConfig,
                    resume: bool = False, log=print, stop_after: int | None = None,
                    minutes: float | None = None, errors: DetectorErrors | None = None,
                    init: str | Path | None = None) -> dict:
    """Trains on prepare_clips() clips into out_dir (checkpoint.pt, regressor.pt, train.json); returns the
    summary. stop_after: stop (with a checkpoint) after this many steps of this call; minutes: after this much
    wall-clock time (both resumable); init: start from the weights of another run (its regressor.pt or
    checkpoint.pt, the same width) instead of a random initialisation (ignored on resume)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seed_everything(config.seed)
    errors = errors or DetectorErrors()
    net = WorldRegressor(config.width, config.root, config.dropout)
    if init is not None and not resume:
        from m3c.io.safe_pickle import load_torch_checkpoint

        state = load_torch_checkpoint(Path(init))
        formulation = _formulation(state)
        if formulation != config.root:
            raise ValueError(f"--init: {init} reads its root orientation as {formulation!r}, this run as "
                             f"{config.root!r} (the orientation head would mean something else)")
        net.load_state_dict(state["model"])
    loss_fn = RegressorLoss(JointKinematics.from_model(body_model), config)
    run = ResumableRun(net, config, out_dir, resume, log)
    start = time.perf_counter()
    net.train()
    while run.step < config.steps:
        batch = make_batch(batch_rng(config.seed, run.step), clips, config, errors)
        out = run_teacher_forced(net, batch, config.teacher_noise, config.sampling_passes,
                                 sampling_prob(config, run.step), config.root_noise)
        terms = loss_fn(out, batch)
        run.optimise(terms["loss"])
        values = {k: terms[k].item() for k in ("loss", "kp3d", "pose", "joints", "root", "velocity",
                                               "contact")}
        stop = run.record(values, f"loss {values['loss']:.4f} (joints {np.sqrt(values['joints']) * 1000:.0f} "
                                  f"mm rms, velocity {np.sqrt(values['velocity']):.2f} m/s rms)", stop_after)
        if stop:
            break
        if minutes is not None and time.perf_counter() - start > 60 * minutes:
            run.save()
            if log:
                log(f"stopping after {minutes} min at step {run.step} (--resume continues)")
            break
    net.eval()
    save_regressor(net, out_dir / "regressor.pt")
    summary = {"config": asdict(config), "init": None if init is None else str(init), "steps_done": run.step,
               "train_clips": len(clips), "history": run.history}
    with atomic_path(out_dir / "train.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def save_regressor(net: WorldRegressor, path: str | Path) -> None:
    """{'model': state dict (WHAM's module names), 'width': width, 'formulation': the root's reading}."""
    save_checkpoint(path, model={k: v.detach().clone() for k, v in net.state_dict().items()}, width=net.width,
                    formulation=net.root)


def _formulation(state: dict) -> str:
    """The root formulation of a regressor.pt or a training checkpoint.pt; files from before the flag were
    trained absolute."""
    return state.get("formulation") or state.get("config", {}).get("root") or "absolute"


def load_regressor(path: str | Path) -> WorldRegressor:
    from m3c.io.safe_pickle import load_torch_checkpoint

    state = load_torch_checkpoint(Path(path))
    width = int(state["width"]) if "width" in state else int(state["config"]["width"])
    net = WorldRegressor(width, _formulation(state))
    net.load_state_dict(state["model"])
    return net.eval()


# Evaluation -------------------------------------------------------------------------------------------------
def procrustes_mpjpe(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(N,) mean joint error after a similarity (rotation, scale, translation) aligns pred (N, J, 3) to
    true."""
    p = pred - pred.mean(1, keepdims=True)
    t = true - true.mean(1, keepdims=True)
    u, s, vt = np.linalg.svd(np.einsum("nji,njk->nik", p, t))
    d = np.sign(np.linalg.det(np.einsum("nij,njk->nik", u, vt)))
    s[:, -1] *= d
    u[:, :, -1] *= d[:, None]
    rot = np.einsum("nij,njk->nik", u, vt)
    scale = s.sum(1) / (p ** 2).sum((1, 2))
    aligned = scale[:, None, None] * np.einsum("nji,nik->njk", p, rot)
    return np.linalg.norm(aligned - t, axis=-1).mean(1)


def _f1(pred: np.ndarray, true: np.ndarray) -> float:
    tp = float((pred & true).sum())
    return 2 * tp / max(float(pred.sum() + true.sum()), 1.0)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = (np.einsum("...ij,...ij->...", a, b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def evaluation_batch(clips, config: RegressorConfig, windows: int = 256, seed: int = 12345,
                     errors: DetectorErrors | None = None) -> dict:
    """A fixed set of held-out windows (their own seed), the same for every model and baseline."""
    return make_batch(np.random.default_rng(seed), clips, config, errors or DetectorErrors(), size=windows)


def mean_training_targets(clips, config: RegressorConfig, windows: int = 256, seed: int = 777,
                          errors: DetectorErrors | None = None) -> dict:
    """The baselines' constants from training windows: the mean body pose (rotations projected to SO(3)) and
    the mean root-frame velocity."""
    batch = make_batch(np.random.default_rng(seed), clips, config, errors or DetectorErrors(), size=windows)
    mean = batch["pose"].double().mean((0, 1)).numpy()
    u, _, vt = np.linalg.svd(mean)
    return {"pose": np.einsum("jik,jkl->jil", u, vt),
            "velocity": batch["velocity"].double().mean((0, 1)).numpy()}


@torch.no_grad()
def evaluate(net: WorldRegressor | None, batch: dict, kinematics: JointKinematics, means: dict,
             chunk: int = 64) -> dict:
    """Held-out figures of the network (None: baselines only) and of the baselines on one evaluation batch:
    pa_mpjpe_mm (camera-frame pose, 24 joints at zero betas), velocity_mps (the root's world velocity error,
    R_root[t-1] v[t], m/s), root_deg (world root orientation), contact_f1. Baselines: mean_pose (the training
    mean body pose), init_pose (the initial pose held), zero / mean velocity with the initial root orientation
    held, contacts always on."""
    loss = RegressorLoss(kinematics, RegressorConfig())
    true_pose = batch["pose"].double()
    b, f = true_pose.shape[:2]
    fps = batch["fps"].double()[:, None, None]
    true_root = batch["root"].double()
    init_root = rotation_6d_to_matrix_rows(batch["init_root"].double())             # (B, 1, 3, 3)
    previous_true = torch.cat([init_root, true_root[:, :-1]], dim=1)
    true_world_v = (previous_true @ batch["velocity"].double()[..., None])[..., 0] * fps
    true_joints = loss.joints(true_pose.float()).double().numpy().reshape(b * f, 24, 3)

    def pose_error(rot):
        return float(procrustes_mpjpe(loss.joints(rot.float()).double().numpy().reshape(b * f, 24, 3),
                                      true_joints).mean() * 1000)

    def velocity_error(root_prev, v):
        return float(((root_prev @ v[..., None])[..., 0] * fps - true_world_v).norm(dim=-1).mean())

    contacts = batch["contacts"].numpy() > 0.5
    held_root = init_root.expand(b, f, 3, 3)
    mean_pose = torch.as_tensor(means["pose"]).expand(b, f, 24, 3, 3).clone()
    mean_pose[:, :, 0] = true_pose[:, :, 0]        # the pose's own root: PA aligns it anyway
    init_pose = rotation_6d_to_matrix_rows(batch["init_pose"].double()).expand(b, f, 24, 3, 3)
    report = {"windows": b, "frames": f, "visible_keypoints": float(batch["visible"].mean()),
              "baselines": {
                  "mean_pose_pa_mpjpe_mm": pose_error(mean_pose),
                  "init_pose_pa_mpjpe_mm": pose_error(init_pose),
                  "zero_velocity_mps": float(true_world_v.norm(dim=-1).mean()),
                  "mean_velocity_mps": velocity_error(
                      held_root, torch.as_tensor(means["velocity"]).expand(b, f, 3) / fps),
                  "held_root_deg": float(_angle_deg(held_root.numpy(), true_root.numpy()).mean()),
                  "always_contact_f1": _f1(np.ones_like(contacts), contacts)}}
    if net is None:
        return report
    net.eval()
    outs = [run_network(net, {k: v[i:i + chunk] for k, v in batch.items()}) for i in range(0, b, chunk)]
    out = {k: torch.cat([o[k] for o in outs]).double() for k in ("pose", "root_6d", "velocity", "contact",
                                                               "keypoints_3d")}
    root = rotation_6d_to_matrix_rows(out["root_6d"])
    report["regressor"] = {
        "pa_mpjpe_mm": pose_error(rotation_6d_to_matrix_rows(out["pose"])),
        "velocity_mps": velocity_error(root[:, :-1], out["velocity"]),
        "velocity_true_root_mps": velocity_error(previous_true, out["velocity"]),
        "root_deg": float(_angle_deg(root[:, 1:].numpy(), true_root.numpy()).mean()),
        "contact_f1": _f1(out["contact"].numpy() > 0, contacts),
        "kp3d_mpjpe_mm": float((out["keypoints_3d"] - batch["kp3d"].double()).norm(dim=-1).mean() * 1000)}
    return report
