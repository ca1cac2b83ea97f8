"""Putting a trained pose prior into the package: its checkpoint, a small held-out sample, the figures on it
and the model card (python/m3c/models/weights/). Run by hand after `m3c train pose-prior`:

    python -m m3c.training.ship RUN_DIR CORPUS_DIR [--command "the training command"]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from m3c.io.atomic import atomic_path, save_npz_atomic
from m3c.mocap.corpus import LICENCES, load_corpus
from m3c.models.vposer import load_vposer
from m3c.training.common import JointKinematics
from m3c.training.pose_prior import (GaussianPosePrior, axis_angle_to_matrix_np, body_poses,
                                     reconstruction_errors, vposer_reconstruct)

SAMPLE_POSES = 1000


def sample_errors(vposer, sample: np.ndarray, mean: np.ndarray, basis: np.ndarray, kinematics) -> dict:
    """Held-out figures on the shipped sample: the prior and the Gaussian baseline (its mean and basis)."""
    true_rot = axis_angle_to_matrix_np(sample.astype(np.float64))
    x = sample.reshape(len(sample), -1).astype(np.float64) - mean
    gauss = ((x @ basis.T) @ basis + mean).reshape(sample.shape)
    return {"vposer": reconstruction_errors(vposer_reconstruct(vposer, sample), true_rot, kinematics),
            "gaussian_pca32": reconstruction_errors(axis_angle_to_matrix_np(gauss), true_rot, kinematics)}


def ship(run_dir: Path, corpus_dir: Path, dest: Path, command: str) -> dict:
    from m3c.body import default_body_model

    metrics = json.loads((run_dir / "metrics.json").read_text())
    train_cfg = json.loads((run_dir / "train.json").read_text())["config"]
    vposer = load_vposer(run_dir / "vposer_v2.ckpt", version="v2")
    kin = JointKinematics.from_model(default_body_model())
    train_clips = load_corpus(corpus_dir, "train")
    held = load_corpus(corpus_dir, "held_out")
    cmu_held = [c for c in held if str(c["licence"]) == LICENCES["cmu"]]
    if not cmu_held:
        raise ValueError("no CMU clip is held out: the shipped sample must be redistributable CMU data")
    poses = body_poses(cmu_held, mirror=False)
    sample = poses[np.linspace(0, len(poses) - 1, min(SAMPLE_POSES, len(poses))).round().astype(int)]
    gauss = GaussianPosePrior(body_poses(train_clips, train_cfg["mirror"]))
    figures = sample_errors(vposer, sample, gauss.mean, gauss.basis, kin)
    cmu_all = sample_errors(vposer, poses, gauss.mean, gauss.basis, kin)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "vposer_v2.ckpt", dest / "vposer_v2.ckpt")
    save_npz_atomic(dest / "pose_prior_sample.npz", body_pose=sample.astype(np.float32),
                    gaussian_mean=gauss.mean.astype(np.float64),
                    gaussian_basis=gauss.basis.astype(np.float64),
                    clips=np.array(sorted(str(c["clip"]) for c in cmu_held)))
    licence = ("non-commercial: trained on the Bandai Namco Research Motiondatasets (CC BY-NC 4.0) and CMU "
               "subsets; the weights inherit CC BY-NC 4.0")
    card = {"model": "M3C pose prior (VPoser v2 architecture, 512 hidden, 32 latent)", "licence": licence,
            "train_clips": metrics["train_clips"], "train_frames": metrics["train_frames"],
            "held_out_clips": metrics["held_out_clips"], "steps": metrics["steps"], "config": train_cfg,
            "command": command, "held_out_all": metrics["held_out"], "held_out_cmu": cmu_all,
            "sample": {"poses": len(sample), **figures}}
    with atomic_path(dest / "pose_prior.json") as tmp:
        tmp.write_text(json.dumps(card, indent=1) + "\n")
    return card


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("corpus_dir", type=Path)
    parser.add_argument("--dest", type=Path,
                        default=Path(__file__).resolve().parents[1] / "models" / "weights")
    parser.add_argument("--command", default="", help="the training command, for the card")
    args = parser.parse_args(argv)
    card = ship(args.run_dir, args.corpus_dir, args.dest, args.command)
    print(json.dumps({k: card[k] for k in ("held_out_all", "held_out_cmu", "sample")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
