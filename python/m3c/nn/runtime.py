"""Thin classes over m3c._core's network runtime; numpy in, numpy (float64) out."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from m3c import _core

_EXPORT_HINT = "create it with: python -m m3c.models.export --out DIR --humor CKPT --vposer PATH"


def _existing(path: str | os.PathLike) -> str:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"exported weights not found: {path}; {_EXPORT_HINT}")
    return str(path)


def read_safetensors(path: str | os.PathLike) -> tuple[dict, dict]:
    """(tensors as float64 arrays, metadata) read by the C++ reader."""
    return _core.read_safetensors(_existing(path))


class HumorPrior:
    """HuMoR's motion-prior terms in C++ from an exported humor.safetensors.

    States are (N, 339) in the ground frame (z up, floor at z = 0), see m3c.models.humor_state.
    transition_nll(x_prev, x_next): NLL of the posterior mean of each pair under the conditional prior.
    latent_nll(x_prev, z): NLL of latents z (N, 48) under the conditional prior of x_prev.
    with_gradient=True also returns the gradients with respect to every input.
    """

    state_dim = 339
    latent_dim = 48

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._core = _core.HumorPrior(_existing(path))

    def transition_nll(self, x_prev, x_next, with_gradient: bool = False):
        return self._core.transition_nll(x_prev, x_next, with_gradient)

    def latent_nll(self, x_prev, z, with_gradient: bool = False):
        return self._core.latent_nll(x_prev, z, with_gradient)

    def sequence_transition_nll(self, states) -> tuple[float, np.ndarray]:
        """Sum over consecutive pairs of states (T, 339) and its gradient (T, 339)."""
        return self._core.sequence_transition_nll(states)

    def encoder_forward(self, pairs) -> np.ndarray:
        """Raw encoder output (N, 96) for canonical pairs (N, 678)."""
        return self._core.encoder_forward(pairs)

    def prior_forward(self, states) -> np.ndarray:
        """Raw prior output (N, 96) for canonical states (N, 339)."""
        return self._core.prior_forward(states)


class VPoser:
    """VPoser v1/v2 in C++ from an exported vposer.safetensors."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._core = _core.VPoser(_existing(path))

    @property
    def version(self) -> str:
        return self._core.version

    @property
    def latent_dim(self) -> int:
        return self._core.latent_dim

    def decode(self, z) -> np.ndarray:
        """Latents (N, latent_dim) -> body joint rotations (N, 21, 3, 3)."""
        return self._core.decode(z)

    def encode(self, pose_body) -> tuple[np.ndarray, np.ndarray]:
        """Axis-angle body pose (N, 21, 3) -> (mean, scale), each (N, latent_dim)."""
        return self._core.encode(pose_body)


def build_humor_states(trans, root_orient, pose_body, joints, fps: float = 30.0,
                       ground_from_world: tuple | None = None) -> np.ndarray:
    """HuMoR states (T-2, 339) computed in C++; arguments as m3c.models.humor_state.build_states with
    root_orient / pose_body in axis-angle and ground_from_world = (R, t) or None."""
    R, t = (None, None) if ground_from_world is None else (np.asarray(v, dtype=np.float64) for v in ground_from_world)
    return _core.humor_build_states(trans, root_orient, pose_body, joints, fps, R, t)


def canonicalize(x, frame_from) -> np.ndarray:
    """States x (N, 339) in the canonical frame of frame_from (N, 339), computed in C++."""
    return _core.humor_canonicalize(x, frame_from)
