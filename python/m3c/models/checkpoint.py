"""Reading official checkpoints from a path the user gives: locating the file, unpickling it without running
foreign code, stripping the prefixes the originals strip, and checking every key and shape against the
architecture, with errors that name the file, what was expected and where the file is obtained."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import torch

from m3c.io import safe_pickle

MODELS_ENV = "M3C_MODELS"


class CheckpointError(ValueError):
    """A checkpoint file is missing, unreadable, or does not match the architecture it is loaded into."""


class CheckpointNotFoundError(CheckpointError, FileNotFoundError):
    """The checkpoint file (or the folder that should hold it) does not exist."""


@dataclass(frozen=True)
class CheckpointSource:
    """Where a model's official weights come from: shown in every error about that model's file."""

    model: str
    default_path: str  # relative to $M3C_MODELS
    obtain: str  # how the user gets the file

    def hint(self) -> str:
        return (f"{self.model} weights: {self.obtain} Pass the file's path, or place it at "
                f"${MODELS_ENV}/{self.default_path}.")


def resolve_path(path: str | os.PathLike | None, source: CheckpointSource) -> Path:
    """The checkpoint path: `path` when given, else $M3C_MODELS/<default_path>. Raises if it does not exist."""
    if path is None:
        root = os.environ.get(MODELS_ENV)
        if not root:
            raise CheckpointNotFoundError(
                f"no {source.model} checkpoint given and ${MODELS_ENV} is not set. {source.hint()}")
        path = Path(root) / source.default_path
    path = Path(path).expanduser()
    if not path.exists():
        raise CheckpointNotFoundError(f"{source.model} checkpoint not found: {path}. {source.hint()}")
    return path


def locate(path: str | os.PathLike | None, models_dir: Path | None, source: CheckpointSource,
           required: bool) -> Path | None:
    """The checkpoint a pipeline node reads: `path` when given, else <models_dir>/<default_path> (models_dir None:
    $M3C_MODELS). Absent: CheckpointNotFoundError when required, else None."""
    if path is None and models_dir is not None:
        path = Path(models_dir) / source.default_path
    try:
        return resolve_path(path, source)
    except CheckpointNotFoundError:
        if required:
            raise
        return None


def newest_file(folder: Path, pattern: str, source: CheckpointSource) -> Path:
    """The most recently modified file matching `pattern` in `folder` (how the originals pick a snapshot)."""
    found = sorted(folder.glob(pattern), key=lambda p: p.stat().st_mtime)
    if not found:
        raise CheckpointNotFoundError(f"{folder} holds no file matching {pattern}. {source.hint()}")
    return found[-1]


def read_checkpoint(path: Path, source: CheckpointSource) -> object:
    """Unpickles a torch checkpoint onto the CPU through torch's weights-only loader (m3c.io.safe_pickle): a
    file that names anything besides tensors, containers and the official files' config containers is refused
    with the global it names, and nothing of it runs."""
    try:
        return safe_pickle.load_torch_checkpoint(path)
    except safe_pickle.UnsafePickleError as err:
        raise CheckpointError(f"{err}. {source.hint()}") from None
    except Exception as err:
        raise CheckpointError(f"{path} is not a readable torch checkpoint ({err}). {source.hint()}") from err


def take_state_dict(checkpoint: object, keys: Iterable[str], path: Path, source: CheckpointSource) -> dict:
    """The first mapping found under `keys` (in order; '' means the checkpoint itself), as a plain dict."""
    tried = []
    for key in keys:
        value = checkpoint if key == "" else (checkpoint.get(key) if isinstance(checkpoint, Mapping) else None)
        tried.append(repr(key) if key else "the file itself")
        if isinstance(value, Mapping) and value and all(isinstance(k, str) for k in value):
            tensors = {k: v for k, v in value.items() if isinstance(v, torch.Tensor)}
            if tensors:
                return tensors
    top = list(checkpoint.keys())[:8] if isinstance(checkpoint, Mapping) else type(checkpoint).__name__
    raise CheckpointError(f"{path}: no state dict of tensors under {', '.join(tried)} (found {top}). "
                          f"{source.hint()}")


def strip_prefix(state: Mapping[str, torch.Tensor], prefix: str) -> dict:
    """Drops `prefix` from the keys that have it (DataParallel's 'module.', Lightning's 'vp_model.')."""
    return {(k[len(prefix):] if k.startswith(prefix) else k): v for k, v in state.items()}


def _describe(shapes: Mapping[str, tuple], limit: int = 12) -> str:
    items = [f"{k} {tuple(s)}" for k, s in list(shapes.items())[:limit]]
    more = len(shapes) - limit
    return ", ".join(items) + (f", ... ({more} more)" if more > 0 else "")


def expected_layout(module: torch.nn.Module) -> dict:
    return {k: tuple(v.shape) for k, v in module.state_dict().items()}


def load_into(module: torch.nn.Module, state: Mapping[str, torch.Tensor], path: Path, source: CheckpointSource,
              ignore_prefixes: tuple[str, ...] = (), optional_suffixes: tuple[str, ...] = ()) -> None:
    """Copies `state` into `module` after checking that every expected key is present with its shape.

    Keys starting with `ignore_prefixes` are dropped (buffers the originals skip too); expected keys ending
    with `optional_suffixes` may be absent (e.g. BatchNorm's num_batches_tracked in files from old torch).
    """
    expected = expected_layout(module)
    state = {k: v for k, v in state.items() if not k.startswith(ignore_prefixes)}
    missing = [k for k in expected if k not in state and not k.endswith(optional_suffixes)]
    unexpected = [k for k in state if k not in expected]
    mismatched = {k: (expected[k], tuple(state[k].shape)) for k in expected
                  if k in state and tuple(state[k].shape) != expected[k]}
    if missing or unexpected or mismatched:
        parts = [f"{path} does not match the {source.model} architecture:"]
        if missing:
            parts.append(f"missing keys {_describe({k: expected[k] for k in missing})};")
        if unexpected:
            parts.append(f"unexpected keys {_describe({k: tuple(state[k].shape) for k in unexpected})};")
        if mismatched:
            parts.append("wrong shapes " + ", ".join(f"{k} expected {e} got {g}"
                                                      for k, (e, g) in list(mismatched.items())[:12]) + ";")
        parts.append(f"expected layout: {_describe(expected)}.")
        parts.append(source.hint())
        raise CheckpointError(" ".join(parts))
    full = module.state_dict()
    with torch.no_grad():
        for key, value in state.items():
            full[key].copy_(value.to(full[key].dtype))


__all__ = ["CheckpointError", "CheckpointNotFoundError", "CheckpointSource", "MODELS_ENV", "expected_layout",
           "load_into", "locate", "newest_file", "read_checkpoint", "resolve_path", "strip_prefix", "take_state_dict"]
