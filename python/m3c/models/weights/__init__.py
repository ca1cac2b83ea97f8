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
