"""Training M3C's own motion prior: HuMoR's layout (m3c.models.humor: posterior encoder, conditional prior and
decoder with contacts, GroupNorm MLPs over the 339-d state of m3c.models.humor_state), narrower when asked, on
a motion-capture corpus of `m3c data mocap`.

Each training sample is a pair of consecutive states (x_t, x_t+1) of a training clip, in HuMoR's ground frame
(z up: the corpus's y-up world turned by ground_from_plane) and in the canonical frame of x_t, with contact
labels for HuMoR's 9 contact joints (a joint within contact_height of the floor and slower than
contact_speed). The loss is HuMoR's with the change normalised (see MotionPrior): |r_dec - r|^2, r the change
from x_t to x_t+1 less constant velocity's, divided by its training spread (mean over the 207 change
dimensions) + contact_weight * BCE(contacts) + kl_weight * KL(q(z | x_t, x_t+1) || p(z | x_t)), the KL weight
rising from 0 over the first kl_warmup of the steps. AdamW, cosine decay, seeded epoch permutations; `--resume`
continues a run exactly. The weights are saved as {'model': state dict (with the normalisation buffers)} with
the widths beside them.
"""

from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from m3c.io.atomic import atomic_path
from m3c.models import humor as humor_module
from m3c.models import humor_state as hs
from m3c.models.rotations import matrix_to_axis_angle
from m3c.training.common import ResumableRun, epoch_batches, save_checkpoint, seed_everything


@dataclass
class MotionPriorConfig:
    steps: int = 20000
    batch_size: int = 256
    lr: float = 5e-4
    weight_decay: float = 1e-5
    hidden: int = 256                 # HuMoR's is 1024 (decoder 1024, 1024, 512)
    kl_weight: float = 1e-3
    kl_warmup: float = 0.2            # share of the steps over which the KL weight rises from 0
    contact_weight: float = 0.1
    contact_height: float = 0.1       # m above the floor
    contact_speed: float = 0.3        # m/s
    seed: int = 0
    checkpoint_minutes: float = 3.0
    history_every: int = 100
    # 1: pairs of consecutive states (teacher forced). K > 1: windows of K transitions rolled out on the prior's
    # own predictions, each step's target the true next state (HuMoR's scheduled sampling, at its end): the prior
    # learns to pull its own drift back instead of compounding it.
    rollout_steps: int = 1


CHANGE_DIM = hs.OUT_CONTACTS.start  # the decoder's 207 change outputs before its 9 contact logits
INPUT_STD_FLOOR = 1e-2    # states: metres, m/s, rotation-matrix entries
OUTPUT_SCALE_FLOOR = 1e-4  # changes per frame
FOOT_JOINTS = (7, 8, 10, 11)  # SMPL ankles and toes
FOOT_CONTACTS = (3, 4, 5, 6)  # their places among HuMoR's 9 contact outputs


def _rotations(x: torch.Tensor, part: slice) -> torch.Tensor:
    return x[..., part].reshape(*x.shape[:-1], -1, 3, 3)


def state_change(x_prev: torch.Tensor, x_next: torch.Tensor) -> torch.Tensor:
    """The change from x_prev to x_next (B, 339 each) in the decoder's layout (B, 207): additive parts as
    differences, rotations as the axis-angle of R_next R_prev^T (applied on the left, as
    apply_decoder_output does), so apply_decoder_output(x_prev, change) gives x_next back."""
    left = lambda part: matrix_to_axis_angle(_rotations(x_next, part) @ _rotations(x_prev, part).transpose(-1, -2))
    d = x_next - x_prev
    return torch.cat([d[:, hs.TRANS], d[:, hs.TRANS_VEL], left(hs.ROOT_ORIENT).flatten(1), d[:, hs.ROOT_ORIENT_VEL],
                      left(hs.POSE_BODY).flatten(1), d[:, hs.JOINTS], d[:, hs.JOINTS_VEL]], dim=-1)


def constant_velocity_change(x_prev: torch.Tensor) -> torch.Tensor:
    """The change constant velocity predicts (B, 207): the translation, the root's rotation and the joints
    move on at their velocities for one frame at HuMoR's 30 fps (the angular velocity is the world-frame
    one, applied on the left); the velocities and the body's joint rotations stay."""
    h = 1.0 / hs.HUMOR_FPS
    zeros = torch.zeros_like
    return torch.cat([x_prev[:, hs.TRANS_VEL] * h, zeros(x_prev[:, hs.TRANS_VEL]), x_prev[:, hs.ROOT_ORIENT_VEL] * h,
                      zeros(x_prev[:, hs.ROOT_ORIENT_VEL]),
                      zeros(x_prev[:, hs.POSE_BODY.start:hs.POSE_BODY.start + 3 * hs.NUM_BODY_JOINTS]),
                      x_prev[:, hs.JOINTS_VEL] * h, zeros(x_prev[:, hs.JOINTS_VEL])], dim=-1)


class MotionPrior(humor_module.HumorModel):
    """HumorModel with widths `hidden` (encoder and prior: four hidden layers; decoder: hidden, hidden,
    hidden / 2); hidden = 1024 is HuMoR's own.

    Two changes from the official networks, because a plain regression of 339 raw numbers was 5x worse than
    constant velocity at one step (14.6 against 2.6 mm): every network sees its states normalised by the
    training set's mean and spread (input_mean, input_std), and the decoder predicts the change's departure
    from constant velocity in units of its training spread (output_scale), so an uninformed decoder already
    moves the body at constant velocity. The normalisation folds exactly into the first Linear of the encoder
    and the prior (`official_layout`), so the exported encoder and prior are HuMoR's networks and run in M3C's
    C++ motion term unchanged; the decoder's constant-velocity path does not fold and stays in torch.
    """

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
        last = self.decoder.net[-1]  # zero: an untrained decoder is constant velocity exactly, contacts at 1/2
        torch.nn.init.zeros_(last.weight)
        torch.nn.init.zeros_(last.bias)
        self.register_buffer("input_mean", torch.zeros(hs.STATE_DIM))
        self.register_buffer("input_std", torch.ones(hs.STATE_DIM))
        self.register_buffer("output_scale", torch.ones(CHANGE_DIM))

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.input_mean) / self.input_std

    def posterior(self, x_prev, x_next):
        out = self.encoder(torch.cat([self.normalise(x_prev), self.normalise(x_next)], dim=-1))
        return out[:, :hs.LATENT_DIM], out[:, hs.LATENT_DIM:]

    def prior(self, x_prev):
        out = self.prior_net(self.normalise(x_prev))
        return out[:, :hs.LATENT_DIM], out[:, hs.LATENT_DIM:]

    def residual(self, x_prev: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """The decoder network's raw output (B, 216): the change's departure from constant velocity in units
        of output_scale, then the contact logits."""
        return self.decoder(torch.cat([self.normalise(x_prev), z], dim=-1))

    def decoder_output(self, x_prev: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """The change in HuMoR's decoder layout (B, 216) (m3c.models.humor_state.apply_decoder_output)."""
        raw = self.residual(x_prev, z)
        change = raw[:, :CHANGE_DIM] * self.output_scale + constant_velocity_change(x_prev)
        return torch.cat([change, raw[:, CHANGE_DIM:]], dim=-1)

    def decode(self, x_prev, z):
        return hs.apply_decoder_output(x_prev, self.decoder_output(x_prev, z))

    def set_normalisation(self, x_prev: torch.Tensor, x_next: torch.Tensor) -> None:
        """The training pairs' statistics: the states' mean and spread, and the spread of the changes'
        departure from constant velocity (floors keep dimensions the canonical frame zeroes finite)."""
        with torch.no_grad():
            self.input_mean.copy_(x_prev.mean(0))
            self.input_std.copy_(x_prev.std(0).clamp_min(INPUT_STD_FLOOR))
            departure = state_change(x_prev, x_next) - constant_velocity_change(x_prev)
            self.output_scale.copy_(departure.std(0).clamp_min(OUTPUT_SCALE_FLOOR))

    def official_layout(self) -> humor_module.HumorModel:
        """The encoder and prior as plain HuMoR networks (the normalisation folded into their first Linear):
        same posterior and prior outputs, widths as this model's. The decoder is left out (its
        constant-velocity path is not in HuMoR's layout)."""
        out = humor_module.HumorModel.__new__(humor_module.HumorModel)
        torch.nn.Module.__init__(out)
        out.encoder = copy.deepcopy(self.encoder)
        out.prior_net = copy.deepcopy(self.prior_net)
        std, mean = self.input_std.double(), self.input_mean.double()
        for net, reps in ((out.encoder, 2), (out.prior_net, 1)):
            first = net.net[0]
            s, m = std.repeat(reps), mean.repeat(reps)
            W = first.weight.double()
            with torch.no_grad():
                first.bias.copy_((first.bias.double() - W @ (m / s)).to(first.bias.dtype))
                first.weight.copy_((W / s).to(first.weight.dtype))
        return out.eval()


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


def _transition_terms(model: MotionPrior, x_prev, x_next, contacts) -> tuple[dict, torch.Tensor]:
    """One transition's loss terms (canonical x_prev -> x_next, contact labels of x_next) and the decoder's raw
    output."""
    q_mean, q_logvar = model.posterior(x_prev, x_next)
    p_mean, p_logvar = model.prior(x_prev)
    z = q_mean + torch.exp(0.5 * q_logvar) * torch.randn_like(q_mean)
    raw = model.residual(x_prev, z)
    # The change in units of its training spread: every dimension of the state counts alike, metres or not.
    target = (state_change(x_prev, x_next) - constant_velocity_change(x_prev)) / model.output_scale
    rec = ((raw[:, :CHANGE_DIM] - target) ** 2).mean()
    bce = F.binary_cross_entropy_with_logits(raw[:, CHANGE_DIM:], contacts)
    kl = 0.5 * (p_logvar - q_logvar + (torch.exp(q_logvar) + (q_mean - p_mean) ** 2) * torch.exp(-p_logvar)
                - 1.0).sum(-1).mean()
    return {"rec": rec, "contact": bce, "kl": kl}, raw


def _weighted(terms: dict, config: MotionPriorConfig, step: int) -> dict:
    # KL annealing (as HuMoR trains): the latent learns to carry the transition before the prior pulls it in.
    warm = min(1.0, step / max(1.0, config.kl_warmup * config.steps))
    total = terms["rec"] + config.contact_weight * terms["contact"] + warm * config.kl_weight * terms["kl"]
    return {"loss": total, **terms}


def _loss(model: MotionPrior, x_prev, x_next, contacts, config: MotionPriorConfig, step: int) -> dict:
    return _weighted(_transition_terms(model, x_prev, x_next, contacts)[0], config, step)


def _train(model: MotionPrior, dataset, loss, out_dir: Path, config: MotionPriorConfig, resume: bool, log,
           stop_after: int | None, summary: dict) -> dict:
    """The training loop both trainers share: seeded epoch batches of dataset, loss(model, *batch, step),
    ResumableRun's steps, checkpoints and history; then motion_prior.pt and train.json (summary's entries
    with the config, steps and history)."""
    run = ResumableRun(model, config, out_dir, resume, log)
    n = len(dataset)
    n_batches = n // config.batch_size
    model.train()
    stop = False
    while run.step < config.steps and not stop:
        epoch, offset = divmod(run.step, n_batches)
        batches = epoch_batches(n, config.batch_size, config.seed, epoch)[offset:]
        loader = torch.utils.data.DataLoader(dataset, batch_sampler=batches.tolist(),
                                             generator=torch.Generator().manual_seed(epoch))
        for batch in loader:
            losses = loss(model, *batch, config, run.step)
            run.optimise(losses["loss"])
            values = {k: float(losses[k].detach()) for k in ("loss", "rec", "contact", "kl")}
            stop = run.record(values, f"loss {values['loss']:.4f} (rec {values['rec']:.5f}, contact "
                                      f"{values['contact']:.3f}, kl {values['kl']:.1f})", stop_after)
            if stop:
                break
    model.eval()
    save_checkpoint(out_dir / "motion_prior.pt", model=model.state_dict(), hidden=config.hidden)
    summary = {"config": asdict(config), "steps_done": run.step, **summary, "history": run.history}
    with atomic_path(out_dir / "train.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
    return summary


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
    model.set_normalisation(x_prev, x_next)
    return _train(model, torch.utils.data.TensorDataset(x_prev, x_next, contacts), _loss, out_dir, config, resume,
                  log, stop_after, {"train_pairs": n})


def windows(clips, model, config: MotionPriorConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Consecutive ground-frame states of the clips cut into windows of rollout_steps + 1 (stride
    rollout_steps): (states (N, K + 1, 339), contacts of states 1..K (N, K, 9))."""
    k = config.rollout_steps
    states, conts = [], []
    for clip in clips:
        if len(clip["pose"]) < k + 3:
            continue
        x, c = clip_states(clip, model, config)
        starts = range(0, len(x) - k, k)
        states += [x[i:i + k + 1] for i in starts]
        conts += [c[i + 1:i + k + 1] for i in starts]
    if not states:
        raise ValueError(f"no clip of {k + 3} frames or more to train the motion prior's rollouts on")
    return torch.stack(states), torch.stack(conts)


def _rollout_loss(model: MotionPrior, states, contacts, config: MotionPriorConfig, step: int) -> dict:
    """The pair loss averaged over a window's transitions, each from the state the prior itself predicted (the
    first from the truth) to the true next state, gradients through the rollout."""
    x = states[:, 0]
    k = states.shape[1] - 1
    total = {"rec": 0.0, "contact": 0.0, "kl": 0.0}
    for i in range(k):
        frame = hs.canonical_frame(x)
        xc = hs.to_canonical(x, frame)
        terms, raw = _transition_terms(model, xc, hs.to_canonical(states[:, i + 1], frame), contacts[:, i])
        total = {key: total[key] + terms[key] / k for key in total}
        change = raw[:, :CHANGE_DIM] * model.output_scale + constant_velocity_change(xc)
        nxt, _ = hs.apply_decoder_output(xc, torch.cat([change, raw[:, CHANGE_DIM:]], dim=-1))
        x = hs.from_canonical(nxt, frame)
    return _weighted(total, config, step)


def train_motion_prior_rollouts(data: tuple, out_dir: str | Path, config: MotionPriorConfig,
                                init: str | Path | None = None, resume: bool = False, log=print,
                                stop_after: int | None = None) -> dict:
    """Trains on windows (m3c.training.motion_prior.windows) rolled out config.rollout_steps transitions, from
    init's weights (a motion_prior.pt or checkpoint.pt: its normalisation kept) or from scratch (normalisation
    from the windows' pairs). Same files as train_motion_prior."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    states, contacts = data
    n = len(states)
    if n < config.batch_size:
        raise ValueError(f"{n} training windows, fewer than one batch ({config.batch_size})")
    seed_everything(config.seed)
    model = MotionPrior(config.hidden)
    if init is not None:
        model.load_state_dict(torch.load(init, map_location="cpu", weights_only=True)["model"])
    else:
        model.set_normalisation(*hs.canonicalize_pair(states[:, :-1].reshape(-1, hs.STATE_DIM),
                                                      states[:, 1:].reshape(-1, hs.STATE_DIM)))
    return _train(model, torch.utils.data.TensorDataset(states, contacts), _rollout_loss, out_dir, config, resume,
                  log, stop_after, {"train_windows": n, "init": str(init) if init else None})


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


def rollout(model: MotionPrior, start: torch.Tensor, steps: int, seed: int = 0) -> tuple[torch.Tensor,
                                                                                          torch.Tensor]:
    """Samples from the prior: from ground-frame states start (B, 339), `steps` transitions, each latent drawn
    from the conditional prior of the state it leaves (seeded). Returns (states (B, steps + 1, 339) in the
    ground frame, contact probabilities (B, steps, 9) of the states after the first)."""
    g = torch.Generator().manual_seed(seed)
    states, probs = [start], []
    x = start
    with torch.no_grad():
        for _ in range(steps):
            frame = hs.canonical_frame(x)
            xc = hs.to_canonical(x, frame)
            mean, logvar = model.prior(xc)
            z = mean + torch.exp(0.5 * logvar) * torch.randn(mean.shape, generator=g, dtype=mean.dtype)
            nxt, logits = model.decode(xc, z)
            x = hs.from_canonical(nxt, frame)
            states.append(x)
            probs.append(torch.sigmoid(logits))
    return torch.stack(states, 1), torch.stack(probs, 1)


def planted_sliding(feet: np.ndarray, planted: np.ndarray, min_frames: int = 3) -> np.ndarray:
    """The horizontal distance (m) each foot joint moves over each planted phase (a run of at least
    min_frames planted frames), from its first frame to its last. feet (..., T, F, 3) ground frame (z up),
    planted (..., T, F) bool. -> (phases,)"""
    feet = feet.reshape(-1, *feet.shape[-3:])
    planted = planted.reshape(-1, *planted.shape[-2:])
    out = []
    for b in range(len(feet)):
        for f in range(feet.shape[2]):
            run = np.flatnonzero(np.diff(np.concatenate([[0], planted[b, :, f].astype(int), [0]])))
            for s, e in zip(run[::2], run[1::2]):
                if e - s >= min_frames:
                    out.append(np.linalg.norm(feet[b, e - 1, f, :2] - feet[b, s, f, :2]))
    return np.asarray(out)


def rollout_figures(model: MotionPrior, starts: torch.Tensor, seconds: float = 2.0, seed: int = 0) -> dict:
    """Rolled-out samples from held-out starting states: do they stay on the ground, and do the feet the prior
    calls planted (contact probability > 0.5) stay put? Sliding in cm per planted phase; floor: the lowest foot
    joint's height per frame (cm)."""
    steps = int(round(seconds * hs.HUMOR_FPS))
    states, probs = rollout(model, starts, steps, seed)
    joints = states[:, 1:, hs.JOINTS].reshape(len(starts), steps, hs.NUM_STATE_JOINTS, 3).numpy()
    feet = joints[:, :, list(FOOT_JOINTS)]
    planted = probs[:, :, list(FOOT_CONTACTS)].numpy() > 0.5
    slide = planted_sliding(feet, planted) * 100
    lowest = feet[..., 2].min(-1) * 100
    finite = bool(np.isfinite(joints).all())
    return {"samples": len(starts), "seconds": seconds, "finite": finite,
            "planted_phases": int(len(slide)),
            "sliding_cm_median": float(np.median(slide)) if len(slide) else None,
            "sliding_cm_mean": float(slide.mean()) if len(slide) else None,
            "sliding_cm_p90": float(np.percentile(slide, 90)) if len(slide) else None,
            "lowest_foot_cm_median": float(np.median(lowest)),
            "frames_on_ground": float(np.mean((lowest > -5) & (lowest < 10))),
            "pelvis_height_m_end": float(np.median(joints[:, -1, 0, 2]))}


def truth_sliding(clips, model, config: MotionPriorConfig) -> dict:
    """The same sliding figure on the held-out clips themselves, their planted feet from the corpus's
    contact labels (the floor the prior is measured against: mocap retargeted is not slide-free either)."""
    slides = []
    for clip in clips:
        if len(clip["pose"]) < 4:
            continue
        states, contacts = clip_states(clip, model, config)
        feet = states[:, hs.JOINTS].reshape(-1, hs.NUM_STATE_JOINTS, 3)[:, list(FOOT_JOINTS)].numpy()
        slides.append(planted_sliding(feet, contacts[:, list(FOOT_CONTACTS)].numpy() > 0.5))
    slide = np.concatenate(slides) * 100 if slides else np.zeros(0)
    return {"planted_phases": int(len(slide)), "sliding_cm_median": float(np.median(slide)) if len(slide) else None,
            "sliding_cm_mean": float(slide.mean()) if len(slide) else None}


def start_states(clips, model, config: MotionPriorConfig, count: int, seed: int = 0) -> torch.Tensor:
    """count ground-frame states drawn (seeded) from the clips, for rollouts."""
    rng = np.random.default_rng(seed)
    pool = [clip_states(c, model, config)[0] for c in clips if len(c["pose"]) >= 4]
    if not pool:
        raise ValueError("no clip of 4 frames or more to start rollouts from")
    picks = []
    for _ in range(count):
        states = pool[rng.integers(len(pool))]
        picks.append(states[rng.integers(len(states))])
    return torch.stack(picks)
