"""Training M3C's own pose prior: VPoser v2's architecture (m3c.models.vposer.VPoserV2, so the existing
loader, the exporter and the C++ runtime take the weights) on a motion-capture corpus of `m3c data mocap`.

The data are the 21 body-joint rotations (SMPL joints 1-21) of every frame of the corpus's training clips, and
their left-right mirror images (reflected across the body's sagittal plane). The loss, per pose, is
    |R_dec - R|_F^2 (mean over joints) + joint_weight * |J_dec - J|^2 (mean over joints, metres, the body
    model's rest skeleton at zero betas, root fixed) + kl_weight * KL(q(z | pose) || N(0, I)),
VPoser's own terms (its mesh term replaced by joints). AdamW, cosine learning-rate decay, a seeded epoch
permutation: a run is deterministic on one thread, and `--resume` continues from a checkpoint exactly as the
run would have gone on. The output is a Lightning-style vposer_v2.ckpt ('state_dict' keys 'vp_model.*') that
m3c.models.vposer.load_vposer(path, version="v2") reads.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from m3c.models.rotations import matrix_to_axis_angle
from m3c.models.vposer import LATENT_DIM, NUM_JOINTS, VPoserV2
from m3c.training.common import (JointKinematics, ResumableRun, epoch_batches, save_checkpoint,
                                 seed_everything)

# SMPL's left/right joint pairs (24-joint indices).
MIRROR_PAIRS = ((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21), (22, 23))


@dataclass
class PosePriorConfig:
    steps: int = 20000
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-5
    hidden: int = 512
    kl_weight: float = 5e-4
    joint_weight: float = 50.0
    mirror: bool = True
    seed: int = 0
    checkpoint_minutes: float = 3.0
    history_every: int = 100          # steps per entry of the loss history (means over those steps)


def mirror_poses(pose: np.ndarray) -> np.ndarray:
    """Left-right mirror images (reflection x -> -x) of SMPL poses (N, 24, 3) axis-angle."""
    out = pose.copy()
    for a, b in MIRROR_PAIRS:
        out[:, [a, b]] = pose[:, [b, a]]
    out[..., 1:] *= -1.0
    return out


def axis_angle_to_matrix_np(aa: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(*aa.shape[:-1], 3, 3)


def body_poses(clips, mirror: bool) -> np.ndarray:
    """(N, 21, 3) float32 body poses of every frame of the clips (dicts with 'pose' (T, 24, 3))."""
    if not clips:
        raise ValueError("no clips to train on: the corpus split is empty")
    pose = np.concatenate([c["pose"] for c in clips]).astype(np.float64)
    if mirror:
        pose = np.concatenate([pose, mirror_poses(pose)])
    return pose[:, 1:1 + NUM_JOINTS].astype(np.float32)


class _Loss(torch.nn.Module):
    def __init__(self, kinematics: JointKinematics, config: PosePriorConfig):
        super().__init__()
        self.kin, self.config = kinematics, config

    def joints(self, body_rot: torch.Tensor) -> torch.Tensor:
        B = body_rot.shape[0]
        eye = torch.eye(3, dtype=body_rot.dtype).expand(B, 1, 3, 3)
        full = torch.cat([eye, body_rot, eye.expand(B, 2, 3, 3)], dim=1)
        return self.kin(full)

    def forward(self, model: VPoserV2, pose: torch.Tensor, rot: torch.Tensor) -> dict:
        mean, scale = model.encode(pose)
        z = mean + scale * torch.randn_like(mean)
        rec = model.decode(z)
        rot_loss = ((rec - rot) ** 2).sum(dim=(-1, -2)).mean()
        joint_loss = ((self.joints(rec) - self.joints(rot)) ** 2).sum(-1).mean()
        kl = (0.5 * (mean ** 2 + scale ** 2 - 1.0) - torch.log(scale.clamp_min(1e-8))).sum(-1).mean()
        total = rot_loss + self.config.joint_weight * joint_loss + self.config.kl_weight * kl
        return {"loss": total, "rot": rot_loss, "joint": joint_loss, "kl": kl}


def train_pose_prior(train_poses: np.ndarray, out_dir: str | Path, model_for_joints, config: PosePriorConfig,
                     resume: bool = False, log=print, stop_after: int | None = None) -> dict:
    """Trains on (N, 21, 3) body poses into out_dir (checkpoint.pt, vposer_v2.ckpt, train.json); returns the
    training summary. stop_after: stop (with a checkpoint) after this many steps of this call (tests)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if len(train_poses) < config.batch_size:
        raise ValueError(f"{len(train_poses)} training poses, fewer than one batch ({config.batch_size})")
    seed_everything(config.seed)
    poses = torch.as_tensor(train_poses, dtype=torch.float32)
    rots = torch.as_tensor(axis_angle_to_matrix_np(train_poses.astype(np.float64)), dtype=torch.float32)
    dataset = torch.utils.data.TensorDataset(poses, rots)
    model = VPoserV2(hidden=config.hidden, latent_dim=LATENT_DIM)
    loss_fn = _Loss(JointKinematics.from_model(model_for_joints), config)
    run = ResumableRun(model, config, out_dir, resume, log)
    n_batches = len(poses) // config.batch_size
    model.train()
    stop = False
    while run.step < config.steps and not stop:
        epoch, offset = divmod(run.step, n_batches)
        batches = epoch_batches(len(poses), config.batch_size, config.seed, epoch)[offset:]
        # Its own generator: creating the iterator would otherwise draw from the global RNG (dropout, the
        # latent samples), and a resumed run creates one mid-epoch.
        loader = torch.utils.data.DataLoader(dataset, batch_sampler=batches.tolist(), num_workers=0,
                                             generator=torch.Generator().manual_seed(epoch))
        for pose, rot in loader:
            losses = loss_fn(model, pose, rot)
            run.optimise(losses["loss"])
            stop = run.record({k: losses[k].item() for k in ("loss", "rot", "joint", "kl")},
                              f"loss {losses['loss'].item():.4f} (rot {losses['rot'].item():.4f}, "
                              f"joint {np.sqrt(losses['joint'].item()) * 1000:.1f} mm rms, "
                              f"kl {losses['kl'].item():.1f})", stop_after)
            if stop:
                break
    model.eval()
    save_vposer_ckpt(model, out_dir / "vposer_v2.ckpt")
    summary = {"config": asdict(config), "steps_done": run.step, "train_poses": len(poses), "history": run.history}
    from m3c.io.atomic import atomic_path

    with atomic_path(out_dir / "train.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def save_vposer_ckpt(model: VPoserV2, path: str | Path) -> None:
    """The weights in VPoser v2's Lightning layout, which load_vposer(path, version='v2') reads."""
    state = {f"vp_model.{k}": v.detach().clone() for k, v in model.state_dict().items()}
    save_checkpoint(path, state_dict=state)


# Evaluation ------------------------------------------------------------------------------------------------
def _geodesic_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) between rotation matrices (..., 3, 3)."""
    cos = (np.einsum("...ij,...ij->...", a, b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def reconstruction_errors(pred_rot: np.ndarray, true_rot: np.ndarray, kinematics: JointKinematics) -> dict:
    """Mean joint-rotation error (degrees) and mean joint-position error (mm; 24 joints, the root at the
    origin, hands at rest) of reconstructed body rotations (N, 21, 3, 3)."""
    loss = _Loss(kinematics, PosePriorConfig())
    with torch.no_grad():
        jp = loss.joints(torch.as_tensor(pred_rot, dtype=torch.float32)).numpy()
        jt = loss.joints(torch.as_tensor(true_rot, dtype=torch.float32)).numpy()
    return {"rotation_deg": float(_geodesic_deg(pred_rot, true_rot).mean()),
            "joint_mm": float(np.linalg.norm(jp - jt, axis=-1).mean() * 1000.0)}


def vposer_reconstruct(model: VPoserV2, poses: np.ndarray) -> np.ndarray:
    """Encode (the posterior mean) then decode: (N, 21, 3) axis-angle -> (N, 21, 3, 3)."""
    model.eval()
    with torch.no_grad():
        mean, _ = model.encode(torch.as_tensor(poses, dtype=torch.float32))
        return model.decode(mean).double().numpy()


class GaussianPosePrior:
    """The baseline: a Gaussian over the 63 axis-angle numbers of a body pose, reconstructing through its top
    `dim` principal components (probabilistic PCA with VPoser's latent size)."""

    def __init__(self, poses: np.ndarray, dim: int = LATENT_DIM):
        x = poses.reshape(len(poses), -1).astype(np.float64)
        self.mean = x.mean(0)
        _, s, vt = np.linalg.svd(x - self.mean, full_matrices=False)
        self.basis = vt[:dim]
        self.variance = s ** 2 / len(x)

    def reconstruct(self, poses: np.ndarray) -> np.ndarray:
        x = poses.reshape(len(poses), -1).astype(np.float64) - self.mean
        return ((x @ self.basis.T) @ self.basis + self.mean).reshape(poses.shape)


def evaluate_pose_prior(model: VPoserV2, train_poses: np.ndarray, test_poses: np.ndarray, kinematics) -> dict:
    """Held-out reconstruction errors of the trained prior and of the Gaussian baseline fitted on the same
    training poses."""
    true_rot = axis_angle_to_matrix_np(test_poses.astype(np.float64))
    gauss = GaussianPosePrior(train_poses)
    base_rot = axis_angle_to_matrix_np(gauss.reconstruct(test_poses))
    return {"held_out_poses": len(test_poses),
            "vposer": reconstruction_errors(vposer_reconstruct(model, test_poses), true_rot, kinematics),
            "gaussian_pca32": reconstruction_errors(base_rot, true_rot, kinematics)}


def to_axis_angle(rot: np.ndarray) -> np.ndarray:
    return matrix_to_axis_angle(torch.as_tensor(rot)).numpy()
