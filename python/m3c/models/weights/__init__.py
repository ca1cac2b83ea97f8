"""M3C's own trained weights, shipped inside the package (MODEL_CARD.md beside them says what each was trained
on, how, how well it does on held-out data and under which licence; all of them together stay under 30 MB).

    vposer_v2.ckpt        the pose prior: VPoser v2's architecture and Lightning layout
                          (m3c.models.vposer.load_vposer(path, version="v2") reads it). Trained on the Bandai
                          Namco Research Motiondatasets (CC BY-NC 4.0) and CMU subsets: non-commercial use
                          only.
    pose_prior.json       its held-out figures, and those of the Gaussian baseline, on pose_prior_sample.npz
    pose_prior_sample.npz held-out body poses (CMU clips kept out of training) the figures are measured on
    motion_prior.pt       the motion prior: HuMoR's layout at a narrower width, with its input normalisation
                          and a constant-velocity decoder path (m3c.training.motion_prior.load_motion_prior).
                          Same data and licence as the pose prior.
    motion_prior.json     its held-out figures (one-step prediction against constant velocity, rollouts), and
                          motion_prior_sample.npz the held-out state pairs they are checked on
    regressor.pt          the world regressor: WHAM's motion encoder and decoders at a narrower width
                          (m3c.training.regressor.load_regressor). Same data and licence as the priors.
    regressor.json        its held-out figures against the baselines', and regressor_sample.npz the held-out
                          clips they are checked on
"""

from __future__ import annotations

import os
import shutil
import tempfile
from importlib import resources
from pathlib import Path


def weights_dir() -> Path:
    return Path(str(resources.files("m3c.models.weights")))


def shipped_vposer_path() -> Path:
    """The shipped pose prior's checkpoint (VPoser v2 layout); FileNotFoundError when this install lacks
    it."""
    path = weights_dir() / "vposer_v2.ckpt"
    if not path.is_file():
        raise FileNotFoundError(f"M3C's pose prior is not in this install ({path}); reinstall m3c")
    return path


def shipped_motion_prior_path() -> Path:
    """The shipped motion prior's checkpoint (m3c.training.motion_prior.load_motion_prior reads it);
    FileNotFoundError when this install lacks it."""
    path = weights_dir() / "motion_prior.pt"
    if not path.is_file():
        raise FileNotFoundError(f"M3C's motion prior is not in this install ({path}); reinstall m3c")
    return path


def shipped_regressor_path() -> Path:
    """The shipped world regressor (m3c.training.regressor.load_regressor reads it); FileNotFoundError when this
    install lacks it."""
    path = weights_dir() / "regressor.pt"
    if not path.is_file():
        raise FileNotFoundError(f"M3C's world regressor is not in this install ({path}); reinstall m3c")
    return path


def _exported_once(checkpoint: Path, file_name: str, export, cache_dir) -> Path:
    """checkpoint exported by export(folder) into cache_dir (default $XDG_CACHE_HOME or ~/.cache, then
    m3c/weights/<the checkpoint's sha256, 16 hex>/file_name) once and reused; the folder is written whole or
    not at all."""
    from m3c.io.manifest import file_sha256

    root = Path(cache_dir) if cache_dir is not None else \
        Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "m3c" / "weights"
    folder = root / file_sha256(checkpoint)[:16]
    path = folder / file_name
    if path.is_file():
        return path
    root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=".export-", dir=root))
    try:
        export(work)
        try:
            work.rename(folder)
        except OSError:  # another process got there first: its folder is as good
            if not path.is_file():
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return path


def shipped_vposer_runtime(cache_dir: str | os.PathLike | None = None) -> Path:
    """The shipped pose prior as the C++ optimizer reads it (vposer.safetensors, m3c.models.export)."""
    from m3c.models.export import export_weights

    checkpoint = shipped_vposer_path()
    return _exported_once(checkpoint, "vposer.safetensors",
                          lambda folder: export_weights(folder, vposer=checkpoint, vposer_version="v2"), cache_dir)


def shipped_humor_runtime(cache_dir: str | os.PathLike | None = None) -> Path:
    """The shipped motion prior as the C++ optimizer reads it (humor.safetensors: its encoder and conditional
    prior in HuMoR's layout, the input normalisation folded in)."""
    from m3c.models.export import export_weights
    from m3c.training.motion_prior import load_motion_prior

    checkpoint = shipped_motion_prior_path()
    return _exported_once(checkpoint, "humor.safetensors",
                          lambda folder: export_weights(folder, humor=load_motion_prior(checkpoint)), cache_dir)
