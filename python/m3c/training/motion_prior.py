"""Training M3C's own motion prior: HuMoR's layout (m3c.models.humor: posterior encoder, conditional prior and
decoder with contacts, GroupNorm MLPs over the 339-d state of m3c.models.humor_state), narrower when asked, on
a motion-capture corpus of `m3c data mocap`.

Each training sample is a pair of consecutive states (x_t, x_t+1) of a training clip, in HuMoR's ground frame
(z up: the corpus's y-up world turned by ground_from_plane) and in the canonical frame of x_t, with contact
labels for HuMoR's 9 contact joints (a joint within contact_height of the floor and slower than
contact_speed). The loss is HuMoR's: |x_dec - x_t+1|^2 (mean over the state) + contact_weight * BCE(contacts)
+ kl_weight * KL(q(z | x_t, x_t+1) || p(z | x_t)). AdamW, cosine decay, seeded epoch permutations; `--resume`
continues a run exactly. The weights are saved as {'model': state dict} (HuMoR's checkpoint layout) with the
widths beside them.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from m3c.io.atomic import atomic_path
from m3c.models import humor as humor_module
from m3c.models import humor_state as hs
from m3c.training.common import ResumableRun, epoch_batches, save_checkpoint, seed_everything


@dataclass
class MotionPriorConfig:
    steps: int = 20000
    batch_size: int = 256
    lr: float = 5e-4
    weight_decay: float = 1e-5
    hidden: int = 256                 # HuMoR's is 1024 (decoder 1024, 1024, 512)
    kl_weight: float = 1e-3
    contact_weight: float = 0.1
    contact_height: float = 0.1       # m above the floor
    contact_speed: float = 0.3        # m/s
    seed: int = 0
    checkpoint_minutes: float = 3.0
    history_every: int = 100


class MotionPrior(humor_module.HumorModel):
    """HumorModel with widths `hidden` (encoder and prior: four hidden layers; decoder: hidden, hidden,
    hidden / 2); hidden = 1024 is HuMoR's own."""

    def __init__(self, hidden: int = 256):
        torch.nn.Module.__init__(self)
        if hidden % humor_module.GROUP_NORM_GROUPS or hidden // 2 % humor_module.GROUP_NORM_GROUPS:
            raise ValueError(f"hidden must be a multiple of {2 * humor_module.GROUP_NORM_GROUPS}, "
                             f"got {hidden}")
        self.hidden = hidden
        latent2 = 2 * hs.LATENT_DIM
        self.encoder = humor_module.GroupNormMLP((2 * hs.STATE_DIM, hidden, hidden, hidden, hidden, latent2))
        self.prior_net = humor_module.GroupNormMLP((hs.STATE_DIM, hidden, hidden, hidden, hidden, latent2))
        self.decoder = humor_module.GroupNormMLP((hs.STATE_DIM + hs.LATENT_DIM, hidden, hidden, hidden // 2,
                                                  hs.DECODER_OUTPUT_DIM), skip_dim=hs.LATENT_DIM)


def clip_states(clip: dict, model, config: MotionPriorConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """(states (T-2, 339) in HuMoR's ground frame, contact labels (T-2, 9)) of a corpus clip; model: the
    m3c.body.BodyModel its joints are posed with."""
    pose = np.asarray(clip["pose"], dtype=np.float64)
    transl = np.asarray(clip["transl"], dtype=np.float64)
    joints = model.joints(pose, np.asarray(clip["betas"], dtype=np.float64), transl)
    ground = hs.ground_from_plane(torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
                                  torch.tensor(0.0, dtype=torch.float64))
    with torch.no_grad():
        states = hs.build_states(torch.as_tensor(transl), torch.as_tensor(pose[:, 0]),
                                 torch.as_tensor(pose[:, 1:22]), torch.as_tensor(joints), float(clip["fps"]),
                                 ground).float()
    at = list(hs.HUMOR_CONTACT_JOINTS)
    height = states[:, hs.JOINTS].reshape(-1, hs.NUM_STATE_JOINTS, 3)[:, at, 2]
    speed = states[:, hs.JOINTS_VEL].reshape(-1, hs.NUM_STATE_JOINTS, 3)[:, at].norm(dim=-1)
    return states, ((height < config.contact_height) & (speed < config.contact_speed)).float()


def pairs(clips, model, config: MotionPriorConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Canonicalised consecutive state pairs of the clips: (x_prev (N, 339), x_next (N, 339), contacts of
    x_next (N, 9))."""
    prev, nxt, cont = [], [], []
    for clip in clips:
        if len(clip["pose"]) < 4:
            continue
        states, contacts = clip_states(clip, model, config)
        a, b = hs.canonicalize_pair(states[:-1], states[1:])
        prev.append(a)
        nxt.append(b)
        cont.append(contacts[1:])
    if not prev:
        raise ValueError("no clip of 4 frames or more to train the motion prior on")
    return torch.cat(prev), torch.cat(nxt), torch.cat(cont)


def _loss(model: MotionPrior, x_prev, x_next, contacts, config: MotionPriorConfig) -> dict:
    q_mean, q_logvar = model.posterior(x_prev, x_next)
    p_mean, p_logvar = model.prior(x_prev)
    z = q_mean + torch.exp(0.5 * q_logvar) * torch.randn_like(q_mean)
    x_dec, logits = model.decode(x_prev, z)
    rec = ((x_dec - x_next) ** 2).mean()
    bce = F.binary_cross_entropy_with_logits(logits, contacts)
    kl = 0.5 * (p_logvar - q_logvar + (torch.exp(q_logvar) + (q_mean - p_mean) ** 2) * torch.exp(-p_logvar)
                - 1.0).sum(-1).mean()
    total = rec + config.contact_weight * bce + config.kl_weight * kl
    return {"loss": total, "rec": rec, "contact": bce, "kl": kl}


def train_motion_prior(data: tuple, out_dir: str | Path, config: MotionPriorConfig, resume: bool = False,
                       log=print, stop_after: int | None = None) -> dict:
    """Trains on (x_prev, x_next, contacts) pairs into out_dir (checkpoint.pt, motion_prior.pt,
    train.json)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    x_prev, x_next, contacts = data
    n = len(x_prev)
    if n < config.batch_size:
        raise ValueError(f"{n} training pairs, fewer than one batch ({config.batch_size})")
    seed_everything(config.seed)
    model = MotionPrior(config.hidden)
    run = ResumableRun(model, config, out_dir, resume, log)
    dataset = torch.utils.data.TensorDataset(x_prev, x_next, contacts)
    n_batches = n // config.batch_size
    model.train()
    stop = False
    while run.step < config.steps and not stop:
        epoch, offset = divmod(run.step, n_batches)
        batches = epoch_batches(n, config.batch_size, config.seed, epoch)[offset:]
        loader = torch.utils.data.DataLoader(dataset, batch_sampler=batches.tolist(),
                                             generator=torch.Generator().manual_seed(epoch))
        for a, b, c in loader:
            losses = _loss(model, a, b, c, config)
            run.optimise(losses["loss"])
            stop = run.record({k: losses[k].item() for k in ("loss", "rec", "contact", "kl")},
                              f"loss {losses['loss'].item():.4f} (rec {losses['rec'].item():.5f}, "
                              f"contact {losses['contact'].item():.3f}, kl {losses['kl'].item():.1f})", stop_after)
            if stop:
                break
    model.eval()
    save_checkpoint(out_dir / "motion_prior.pt", model=model.state_dict(), hidden=config.hidden)
    summary = {"config": asdict(config), "steps_done": run.step, "train_pairs": n, "history": run.history}
    with atomic_path(out_dir / "train.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def load_motion_prior(path: str | Path) -> MotionPrior:
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = MotionPrior(int(state["hidden"]))
    model.load_state_dict(state["model"])
    return model.eval()


def one_step_errors(model: MotionPrior, x_prev: torch.Tensor, x_next: torch.Tensor) -> dict:
    """One-step prediction of the next state's 22 joints (mm, mean over joints and pairs): the prior's (the
    decoder at the conditional prior's mean latent) and constant velocity's (joints + joints_vel / 30 s)."""
    with torch.no_grad():
        mean, _ = model.prior(x_prev)
        pred, _ = model.decode(x_prev, mean)
    true = x_next[:, hs.JOINTS].reshape(-1, 22, 3)
    prior_joints = pred[:, hs.JOINTS].reshape(-1, 22, 3)
    const = (x_prev[:, hs.JOINTS] + x_prev[:, hs.JOINTS_VEL] / hs.HUMOR_FPS).reshape(-1, 22, 3)
    return {"pairs": len(x_prev), "motion_prior_mm": float((prior_joints - true).norm(dim=-1).mean() * 1000),
            "constant_velocity_mm": float((const - true).norm(dim=-1).mean() * 1000)}
