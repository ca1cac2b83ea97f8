"""What M3C's training commands share: determinism, checkpoints that resume exactly, progress lines, and the
body-model kinematics the losses and the evaluations measure joints with."""

from __future__ import annotations

import random
import time
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
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--resume: no checkpoint at {path}")
    return torch.load(path, map_location="cpu", weights_only=False)


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
