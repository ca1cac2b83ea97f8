"""Putting a trained world regressor into the package: its weights, a small held-out sample (windows of
held-out CMU clips through virtual cameras, as evaluation_batch draws them), the figures on it and a
MODEL_CARD.md section (python/m3c/models/weights/). Run by hand after `m3c train regressor`:

    python -m m3c.training.ship_regressor RUN_DIR CORPUS_DIR [--command "the training command"]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import torch

from m3c.io.atomic import atomic_path, save_npz_atomic
from m3c.mocap.corpus import LICENCES, load_corpus
from m3c.training.common import JointKinematics
from m3c.training.regressor import (RegressorConfig, evaluate, evaluation_batch, load_regressor,
                                    mean_training_targets, prepare_clips)

SAMPLE_WINDOWS = 32
CARD_START = "<!-- regressor card -->"


def sample_figures(net, sample: dict, kinematics) -> dict:
    """evaluate() on a shipped sample (arrays as save_sample writes them)."""
    batch = {k: torch.as_tensor(v) for k, v in sample.items() if not k.startswith("mean_")}
    batch["mask"] = batch["mask"].bool()
    means = {"pose": sample["mean_pose"], "velocity": sample["mean_velocity"]}
    return evaluate(net, batch, kinematics, means)


def ship(run_dir: Path, corpus_dir: Path, dest: Path, command: str) -> dict:
    from m3c.body import default_body_model

    model = default_body_model()
    metrics = json.loads((run_dir / "metrics.json").read_text())
    train_cfg = json.loads((run_dir / "train.json").read_text())["config"]
    config = RegressorConfig(frames=train_cfg["frames"], width=train_cfg["width"])
    net = load_regressor(run_dir / "regressor.pt")
    train_clips = load_corpus(corpus_dir, "train")
    held = load_corpus(corpus_dir, "held_out")
    if {str(c["clip"]) for c in train_clips} & {str(c["clip"]) for c in held}:
        raise ValueError("a held-out clip was trained on")
    cmu = [c for c in held if str(c["licence"]) == LICENCES["cmu"]]
    if not cmu:
        raise ValueError("no CMU clip is held out: the shipped sample must be redistributable CMU data")
    means = mean_training_targets(prepare_clips(train_clips, model, config.frames), config)
    batch = evaluation_batch(prepare_clips(cmu, model, config.frames), config, windows=SAMPLE_WINDOWS)
    sample = {k: v.numpy() for k, v in batch.items()}
    sample.update(mean_pose=means["pose"], mean_velocity=means["velocity"])
    kinematics = JointKinematics.from_model(model)
    figures = sample_figures(net, sample, kinematics)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "regressor.pt", dest / "regressor.pt")
    save_npz_atomic(dest / "regressor_sample.npz", **sample)
    card = {"model": f"M3C world regressor (WHAM layout, width {config.width})",
            "licence": "non-commercial: trained on the Bandai Namco Research Motiondatasets (CC BY-NC 4.0) "
                       "and CMU subsets; the weights inherit CC BY-NC 4.0",
            "train_clips": metrics["train_clips"], "held_out_clips": metrics["held_out_clips"],
            "steps": metrics["steps"], "config": train_cfg, "command": command,
            "held_out": metrics["held_out"], "sample": figures,
            "sample_clips": sorted(str(c["clip"]) for c in cmu)}
    with atomic_path(dest / "regressor.json") as tmp:
        tmp.write_text(json.dumps(card, indent=1) + "\n")
    card_file = dest / "MODEL_CARD.md"
    text = card_file.read_text() if card_file.is_file() else ""
    text = text.split(CARD_START)[0].rstrip("\n")
    with atomic_path(card_file) as tmp:
        tmp.write_text(text + "\n\n" + model_card(card))
    return card


def _row(name: str, figures: dict) -> str:
    r, b = figures["regressor"], figures["baselines"]
    return (f"| {name} | {figures['windows']} x {figures['frames']} | {r['pa_mpjpe_mm']:.1f} "
            f"({b['mean_pose_pa_mpjpe_mm']:.1f} / {b['init_pose_pa_mpjpe_mm']:.1f}) | "
            f"{r['velocity_mps']:.3f} "
            f"({b['zero_velocity_mps']:.3f} / {b['mean_velocity_mps']:.3f}) | {r['root_deg']:.1f} "
            f"({b['held_root_deg']:.1f}) | {r['contact_f1']:.3f} ({b['always_contact_f1']:.3f}) |")


def model_card(card: dict) -> str:
    """The regressor's MODEL_CARD.md section (after CARD_START, which the pose prior's card keeps)."""
    cfg = card["config"]
    return "\n".join([
        CARD_START,
        "# M3C world regressor (`regressor.pt`)",
        "",
        f"WHAM's motion encoder, trajectory decoder and motion decoder (m3c.models.wham, the official module "
        f"names) at width {cfg['width']} (WHAM's: 512), without image features. "
        "`m3c.training.regressor.load_regressor(path)` reads it.",
        "",
        "**Licence: non-commercial** (CC BY-NC 4.0, from the Bandai Namco Research Motiondatasets; the CMU "
        "part: \"The data used in this project was obtained from mocap.cs.cmu.edu. The database was created "
        "with funding from NSF EIA-0196217.\")",
        "",
        "## Training",
        "",
        f"- {card['train_clips']} training clips of the corpus (`m3c data mocap`), "
        f"{card['held_out_clips']} held out by clip; windows of "
        f"{cfg['frames']} frames through virtual cameras with M3C's measured detector errors "
        "(m3c.training.virtual_camera).",
        f"- {card['steps']} AdamW steps of {cfg['batch_size']} windows (of {cfg['steps']} planned), learning "
        f"rate {cfg['lr']:g}, cosine decay, teacher-forced decoders, seed {cfg['seed']}, one thread.",
        f"- Command: `{card['command']}`",
        "",
        "## Held-out figures",
        "",
        "Autoregressive, as at inference, on fixed held-out windows. PA-MPJPE: the camera-frame pose's 24 "
        "joints at zero betas; velocity: the root's world velocity error; baselines in brackets (the "
        "training mean pose / the initial pose held; zero / mean root velocity; the initial root orientation "
        "held; contacts always on).",
        "",
        "| held-out set | windows x frames | PA-MPJPE mm | velocity m/s | root deg | contact F1 |",
        "|---|---|---|---|---|---|",
        _row("held-out clips", card["held_out"]),
        _row("shipped sample (regressor_sample.npz, CMU)", card["sample"]),
        "",
        "tests/python/test_shipped_regressor.py checks the shipped sample's figures.",
        "",
    ])


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
    print(json.dumps(card["sample"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
