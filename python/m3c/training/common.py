"""What M3C's training commands share: determinism, checkpoints that resume exactly, progress lines, and the
body-model kinematics the losses and the evaluations measure joints with."""

from __future__ import annotations

import random
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from m3c.io.atomic import atomic_path


def seed_everything(seed: int) -> None:
    """Seeds Python, numpy and torch and makes torch pick deterministic kernels."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True)


def save_checkpoint(path: str | Path, **state) -> None:
    """torch.save, atomically (a crash leaves the previous checkpoint)."""
    with atomic_path(path, suffix=".pt") as tmp:
        torch.save(state, tmp)


def load_checkpoint(path: str | Path) -> dict:
    """A training checkpoint, through the loader that runs no code from the file (a run folder can be handed
    over like any checkpoint)."""
    from m3c.io.safe_pickle import load_torch_checkpoint

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--resume: no checkpoint at {path}")
    return load_torch_checkpoint(path)


def epoch_batches(n: int, batch: int, seed: int, epoch: int) -> torch.Tensor:
    """(n // batch, batch) indices of an epoch: a permutation seeded by (seed, epoch) alone, so a resumed run
    draws the batches the uninterrupted one would."""
    g = torch.Generator().manual_seed(seed * 1000003 + epoch)
    return torch.randperm(n, generator=g)[: (n // batch) * batch].reshape(-1, batch)


class ResumableRun:
    """The part of a training run both trainers share: AdamW with cosine decay, the step count and the loss
    history, checkpoints every config.checkpoint_minutes (out_dir/checkpoint.pt) that `resume` continues exactly,
    and the progress lines. config: a dataclass with steps, lr, weight_decay, checkpoint_minutes, history_every."""

    def __init__(self, model: torch.nn.Module, config, out_dir: str | Path, resume: bool, log=print):
        self.model, self.config = model, config
        self.optimizer = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(self.optimizer, T_max=config.steps,
                                                                    eta_min=config.lr * 0.02)
        self.step, self.history = 0, []
        self.path = Path(out_dir) / "checkpoint.pt"
        if resume:
            state = load_checkpoint(self.path)
            if state["config"] != asdict(config):
                changed = {k for k in asdict(config) if state["config"].get(k) != asdict(config)[k]}
                raise ValueError(f"--resume: the checkpoint was trained with other settings ({sorted(changed)}); "
                                 "resume with the same ones, or start a new --out")
            model.load_state_dict(state["model"])
            self.optimizer.load_state_dict(state["optimizer"])
            self.scheduler.load_state_dict(state["scheduler"])
            torch.set_rng_state(state["torch_rng"])
            self.step, self.history = state["step"], state["history"]
            if log:
                log(f"resumed from {self.path} at step {self.step}")
        self.start_step = self.step
        self.progress = Progress(config.steps, log)
        self._last_save = time.perf_counter()
        self._running: list[list[float]] = []

    def save(self) -> None:
        save_checkpoint(self.path, model=self.model.state_dict(), optimizer=self.optimizer.state_dict(),
                        scheduler=self.scheduler.state_dict(), torch_rng=torch.get_rng_state(), step=self.step,
                        history=self.history, config=asdict(self.config))

    def optimise(self, loss: torch.Tensor) -> None:
        """One step of the optimiser and the schedule on `loss`."""
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.scheduler.step()
        self.step += 1

    def record(self, values: dict[str, float], text: str, stop_after: int | None = None) -> bool:
        """After a step: the history (means over history_every steps), a progress line, a checkpoint when due.
        True when the run should stop (all steps done, or stop_after steps in this call)."""
        step, config = self.step, self.config
        self._running.append(list(values.values()))
        if step % config.history_every == 0 or step == config.steps:
            mean = np.mean(self._running, axis=0)
            self.history.append({"step": step, **dict(zip(values, mean))})
            self._running = []
        self.progress.update(step, text)
        stop = step >= config.steps or (stop_after is not None and step - self.start_step >= stop_after)
        if stop or time.perf_counter() - self._last_save > 60 * config.checkpoint_minutes:
            self.save()
            self._last_save = time.perf_counter()
        return stop


class Progress:
    """Progress lines with the loss and the time left, at most one every `every` seconds."""

    def __init__(self, total_steps: int, log=print, every: float = 10.0):
        self.total, self.log, self.every = total_steps, log, every
        self.start = time.perf_counter()
        self.first_step: int | None = None
        self.last = -np.inf

    def update(self, step: int, text: str, force: bool = False) -> None:
        now = time.perf_counter()
        if self.first_step is None:
            self.first_step, self.start = step, now
            return
        if not self.log or (not force and now - self.last < self.every):
            return
        self.last = now
        rate = (step - self.first_step) / max(now - self.start, 1e-9)
        left = (self.total - step) / rate if rate > 0 else float("nan")
        self.log(f"step {step}/{self.total} {text} | {rate:.1f} steps/s, {left / 60:.1f} min left")


class JointKinematics(torch.nn.Module):
    """Forward kinematics of the body model's 24 joints at fixed betas (rest joints as a buffer):
    local rotations (B, 24, 3, 3) -> joint positions (B, 24, 3), the root at the origin."""

    def __init__(self, rest_joints: np.ndarray, parents):
        super().__init__()
        self.register_buffer("rest", torch.as_tensor(np.asarray(rest_joints), dtype=torch.float32))
        self.parents = [int(p) for p in parents]

    @classmethod
    def from_model(cls, model, betas=None) -> JointKinematics:
        betas = np.zeros(model.num_betas) if betas is None else betas
        rest = model.joints(np.zeros((1, model.num_joints, 3)), betas)[0]
        return cls(rest - rest[0], model.parents)

    def forward(self, rotations: torch.Tensor) -> torch.Tensor:
        world = [rotations[:, 0]]
        pos = [torch.zeros_like(rotations[:, 0, :, 0])]
        for j in range(1, len(self.parents)):
            p = self.parents[j]
            offset = (self.rest[j] - self.rest[p]).to(rotations.dtype)
            pos.append(pos[p] + torch.einsum("bij,j->bi", world[p], offset))
            world.append(world[p] @ rotations[:, j])
        return torch.stack(pos, dim=1)
