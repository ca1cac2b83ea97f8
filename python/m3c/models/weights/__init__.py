"""M3C's own trained weights, shipped inside the package (MODEL_CARD.md beside them says what each was trained
on, how, how well it does on held-out data and under which licence; all of them together stay under 30 MB).

    vposer_v2.ckpt        the pose prior: VPoser v2's architecture and Lightning layout
                          (m3c.models.vposer.load_vposer(path, version="v2") reads it). Trained on the Bandai
                          Namco Research Motiondatasets (CC BY-NC 4.0) and CMU subsets: non-commercial use
                          only.
    pose_prior.json       its held-out figures, and those of the Gaussian baseline, on pose_prior_sample.npz
    pose_prior_sample.npz held-out body poses (CMU clips kept out of training) the figures are measured on
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


def shipped_vposer_runtime(cache_dir: str | os.PathLike | None = None) -> Path:
    """The shipped pose prior as the C++ optimizer reads it (vposer.safetensors, m3c.models.export), exported once
    from vposer_v2.ckpt into cache_dir (default $XDG_CACHE_HOME or ~/.cache, then m3c/weights/<the checkpoint's
    sha256, 16 hex>/) and reused; the folder is written whole or not at all."""
    from m3c.io.manifest import file_sha256
    from m3c.models.export import export_weights

    checkpoint = shipped_vposer_path()
    root = Path(cache_dir) if cache_dir is not None else \
        Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "m3c" / "weights"
    folder = root / file_sha256(checkpoint)[:16]
    path = folder / "vposer.safetensors"
    if path.is_file():
        return path
    root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=".vposer-", dir=root))
    try:
        export_weights(work, vposer=checkpoint, vposer_version="v2")
        try:
            work.rename(folder)
        except OSError:  # another process got there first: its folder is as good
            if not path.is_file():
                raise
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return path
