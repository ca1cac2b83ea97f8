"""Putting a trained prior into the package: its checkpoint, a small held-out sample, the figures on it and
the model card (python/m3c/models/weights/). Run by hand after `m3c train pose-prior` or `m3c train
motion-prior`:

    python -m m3c.training.ship RUN_DIR CORPUS_DIR [--command "the training command"]   (the pose prior)
    python -m m3c.training.ship RUN_DIR CORPUS_DIR --motion [--command ...]              (the motion prior)
    python -m m3c.training.ship RUN_DIR CORPUS_DIR --regressor [--command ...]           (the world regressor)

MODEL_CARD.md is written from the figures of what is shipped (pose_prior.json, motion_prior.json,
regressor.json).
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
# Every weights file M3C ships is trained on this corpus and inherits its most restrictive licence.
WEIGHTS_LICENCE = ("non-commercial: trained on the Bandai Namco Research Motiondatasets (CC BY-NC 4.0) and CMU "
                   "subsets; the weights inherit CC BY-NC 4.0")


def clip_sample_arrays(sample: list[dict], contacts: bool = False) -> dict:
    """The arrays of a shipped sample of clips (their frames concatenated, `lengths` to split them)."""
    arrays = {"clips": np.array([str(c["clip"]) for c in sample]),
              "lengths": np.array([len(c["pose"]) for c in sample]),
              "pose": np.concatenate([c["pose"] for c in sample]).astype(np.float32),
              "transl": np.concatenate([c["transl"] for c in sample]).astype(np.float32)}
    if contacts:
        arrays["contacts"] = np.concatenate([c["contacts"] for c in sample]).astype(bool)
    arrays["betas"] = np.stack([np.asarray(c["betas"], dtype=np.float32) for c in sample])
    arrays["fps"] = np.array([float(c["fps"]) for c in sample], dtype=np.float32)
    return arrays


def sample_errors(vposer, sample: np.ndarray, mean: np.ndarray, basis: np.ndarray, kinematics) -> dict:
    """Held-out figures on the shipped sample: the prior and the Gaussian baseline (its mean and basis)."""
    true_rot = axis_angle_to_matrix_np(sample.astype(np.float64))
    x = sample.reshape(len(sample), -1).astype(np.float64) - mean
    gauss = ((x @ basis.T) @ basis + mean).reshape(sample.shape)
    return {"vposer": reconstruction_errors(vposer_reconstruct(vposer, sample), true_rot, kinematics),
            "gaussian_pca32": reconstruction_errors(axis_angle_to_matrix_np(gauss), true_rot, kinematics)}


def ship(run_dir: Path, corpus_dir: Path, dest: Path, command: str, eval_dir: Path | None = None,
         note: str = "") -> dict:
    """corpus_dir: the corpus the run trained on (its training split fits the baseline); eval_dir: the corpus
    whose held-out split is measured (default corpus_dir; a later, larger conversion of the same sources keeps
    the held-out clips held out, the split being a hash of the clip id)."""
    from m3c.body import default_body_model

    metrics = json.loads((run_dir / "metrics.json").read_text())
    train_cfg = json.loads((run_dir / "train.json").read_text())["config"]
    vposer = load_vposer(run_dir / "vposer_v2.ckpt", version="v2")
    kin = JointKinematics.from_model(default_body_model())
    train_clips = load_corpus(corpus_dir, "train")
    held = load_corpus(eval_dir or corpus_dir, "held_out")
    trained = {str(c["clip"]) for c in train_clips}
    if trained & {str(c["clip"]) for c in held}:
        raise ValueError("a held-out clip of the evaluation corpus was trained on")
    cmu_held = [c for c in held if str(c["licence"]) == LICENCES["cmu"]]
    if not cmu_held:
        raise ValueError("no CMU clip is held out: the shipped sample must be redistributable CMU data")
    poses = body_poses(cmu_held, mirror=False)
    sample = poses[np.linspace(0, len(poses) - 1, min(SAMPLE_POSES, len(poses))).round().astype(int)]
    gauss = GaussianPosePrior(body_poses(train_clips, train_cfg["mirror"]))
    figures = sample_errors(vposer, sample, gauss.mean, gauss.basis, kin)
    everything = body_poses(held, mirror=False)
    held_all = {"held_out_poses": len(everything),
                **sample_errors(vposer, everything, gauss.mean, gauss.basis, kin)}
    cmu_all = {"held_out_poses": len(poses), **sample_errors(vposer, poses, gauss.mean, gauss.basis, kin)}
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "vposer_v2.ckpt", dest / "vposer_v2.ckpt")
    save_npz_atomic(dest / "pose_prior_sample.npz", body_pose=sample.astype(np.float32),
                    gaussian_mean=gauss.mean.astype(np.float64),
                    gaussian_basis=gauss.basis.astype(np.float64),
                    clips=np.array(sorted(str(c["clip"]) for c in cmu_held)))
    card = {"model": "M3C pose prior (VPoser v2 architecture, 512 hidden, 32 latent)",
            "licence": WEIGHTS_LICENCE,
            "train_clips": metrics["train_clips"], "train_frames": metrics["train_frames"],
            "held_out_clips": len(held), "steps": metrics["steps"], "config": train_cfg,
            "command": command, "note": note, "held_out_all": held_all, "held_out_cmu": cmu_all,
            "sample": {"poses": len(sample), **figures}}
    with atomic_path(dest / "pose_prior.json") as tmp:
        tmp.write_text(json.dumps(card, indent=1) + "\n")
    write_model_card(dest)
    return card


SAMPLE_CLIP_FRAMES = 300  # frames of each held-out CMU clip in the motion prior's shipped sample
SAMPLE_ROLLOUTS = 32


def motion_sample_figures(prior, clips, body_model, config) -> dict:
    """The motion prior's figures on clips: one-step prediction against constant velocity, rollouts of 2 s
    from states drawn from them, and the clips' own sliding."""
    from m3c.training.motion_prior import one_step_errors, pairs, rollout_figures, start_states, truth_sliding

    x_prev, x_next, _ = pairs(clips, body_model, config)
    starts = start_states(clips, body_model, config, count=SAMPLE_ROLLOUTS, seed=config.seed)
    return {"one_step": one_step_errors(prior, x_prev, x_next),
            "rollouts": rollout_figures(prior, starts, seconds=2.0, seed=config.seed),
            "truth_sliding": truth_sliding(clips, body_model, config)}


def ship_motion_prior(run_dir: Path, corpus_dir: Path, dest: Path, command: str, note: str = "") -> dict:
    """The motion prior of run_dir into dest: motion_prior.pt, motion_prior_sample.npz (the first
    SAMPLE_CLIP_FRAMES frames of each held-out CMU clip), motion_prior.json (held-out figures: all held-out
    clips, the sample) and the model card."""
    from m3c.body import default_body_model
    from m3c.training.motion_prior import MotionPriorConfig, load_motion_prior

    metrics = json.loads((run_dir / "metrics.json").read_text())
    train_cfg = json.loads((run_dir / "train.json").read_text())["config"]
    config = MotionPriorConfig(**train_cfg)
    prior = load_motion_prior(run_dir / "motion_prior.pt")
    model = default_body_model()
    trained = {str(c["clip"]) for c in load_corpus(corpus_dir, "train")}
    held = load_corpus(corpus_dir, "held_out")
    if trained & {str(c["clip"]) for c in held}:
        raise ValueError("a held-out clip was trained on")
    cmu = [c for c in held if str(c["licence"]) == LICENCES["cmu"] and len(c["pose"]) >= 4]
    if not cmu:
        raise ValueError("no CMU clip is held out: the shipped sample must be redistributable CMU data")
    sample = [{k: (v[:SAMPLE_CLIP_FRAMES] if k in ("pose", "transl") else v) for k, v in c.items()} for c in cmu]
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "motion_prior.pt", dest / "motion_prior.pt")
    save_npz_atomic(dest / "motion_prior_sample.npz", **clip_sample_arrays(sample))
    card = {"model": f"M3C motion prior (HuMoR layout, {config.hidden} hidden, 48 latent)",
            "licence": WEIGHTS_LICENCE,
            "train_clips": metrics["train_clips"], "train_pairs": metrics["train_pairs"],
            "held_out_clips": len(held), "steps": metrics["steps"], "config": train_cfg, "command": command,
            "note": note, "held_out_all": {k: metrics[k] for k in ("held_out_one_step", "held_out_rollouts",
                                                                    "held_out_truth_sliding")},
            "sample": {"clips": len(sample), **motion_sample_figures(prior, sample, model, config)}}
    with atomic_path(dest / "motion_prior.json") as tmp:
        tmp.write_text(json.dumps(card, indent=1) + "\n")
    write_model_card(dest)
    return card


SAMPLE_WINDOWS = 64  # held-out windows of the regressor's shipped sample (evaluation_batch's fixed seed)


def regressor_sample_figures(net, clips, body_model, config, means: dict) -> dict:
    """The regressor's held-out figures (m3c.training.regressor.evaluate) on SAMPLE_WINDOWS windows of clips,
    the baselines' constants (means: pose (24, 3, 3), velocity (3,)) from the training windows."""
    from m3c.training.regressor import evaluate, evaluation_batch, prepare_clips

    batch = evaluation_batch(prepare_clips(clips, body_model, config.frames), config, windows=SAMPLE_WINDOWS)
    return evaluate(net, batch, JointKinematics.from_model(body_model), means)


def ship_regressor(run_dir: Path, corpus_dir: Path, dest: Path, command: str, note: str = "") -> dict:
    """The world regressor of run_dir into dest: regressor.pt, regressor_sample.npz (the first
    SAMPLE_CLIP_FRAMES frames of each held-out CMU clip long enough for a window, and the baselines'
    constants), regressor.json (held-out figures: every held-out clip as the training command measured them,
    the sample) and the model card."""
    from m3c.body import default_body_model
    from m3c.training.regressor import config_from_dict, load_regressor, mean_training_targets, prepare_clips

    metrics = json.loads((run_dir / "metrics.json").read_text())
    train_cfg = json.loads((run_dir / "train.json").read_text())["config"]
    config = config_from_dict(train_cfg)
    net = load_regressor(run_dir / "regressor.pt")
    model = default_body_model()
    train_clips = load_corpus(corpus_dir, "train")
    held = load_corpus(corpus_dir, "held_out")
    if {str(c["clip"]) for c in train_clips} & {str(c["clip"]) for c in held}:
        raise ValueError("a held-out clip was trained on")
    cmu = [c for c in held if str(c["licence"]) == LICENCES["cmu"] and len(c["pose"]) > config.frames]
    if not cmu:
        raise ValueError("no CMU clip is held out: the shipped sample must be redistributable CMU data")
    keep = ("pose", "transl", "contacts")
    sample = [{k: (v[:SAMPLE_CLIP_FRAMES] if k in keep else v) for k, v in c.items()} for c in cmu]
    # The baselines' constants as the training command drew them (its default seed and windows).
    means = mean_training_targets(prepare_clips(train_clips, model, config.frames), config)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "regressor.pt", dest / "regressor.pt")
    save_npz_atomic(dest / "regressor_sample.npz", **clip_sample_arrays(sample, contacts=True),
                    mean_pose=means["pose"], mean_velocity=means["velocity"])
    card = {"model": f"M3C world regressor (WHAM layout, width {config.width}, root {config.root})",
            "licence": WEIGHTS_LICENCE, "train_clips": metrics["train_clips"],
            # the frames of the clips it drew windows from (long enough for one)
            "train_frames": int(sum(len(c["pose"]) for c in train_clips if len(c["pose"]) > config.frames)),
            "held_out_clips": len(held),
            "steps": metrics["steps"], "config": train_cfg, "command": command, "note": note,
            "held_out_all": metrics["held_out"],
            "sample": {"clips": len(sample), **regressor_sample_figures(net, sample, model, config, means)}}
    with atomic_path(dest / "regressor.json") as tmp:
        tmp.write_text(json.dumps(card, indent=1) + "\n")
    write_model_card(dest)
    return card


def regressor_model_card(card: dict) -> str:
    cfg = card["config"]
    lines = [
        "# M3C world regressor (`regressor.pt`)",
        "",
        f"WHAM's motion encoder, trajectory decoder and motion decoder (`m3c.models.wham`, the official module "
        f"names) at width {cfg['width']} (WHAM's: 512), without image features, integrator or trajectory "
        "refiner, trained by M3C on the corpus of `m3c data mocap` (../shared/data/mocap_corpus: Bandai Namco "
        "datasets 1 and 2, CMU subsets) seen through virtual cameras (`m3c.training.regressor`, "
        "`m3c.training.virtual_camera`: random heights, distances, focal lengths and five camera motions, "
        "keypoints corrupted by the measured detector errors, occlusions and truncation). The root orientation "
        f"is read as `{cfg['root']}` (`formulation` in the file; `m3c.training.regressor.load_regressor` reads "
        "it).",
        "",
        "**Licence: non-commercial** (CC BY-NC 4.0, inherited from the Bandai Namco Research Motiondatasets), as "
        "the priors'.",
        "",
        "## Training",
        "",
        f"- {card['train_clips']} training clips, {card['train_frames']} frames at 30 fps; "
        f"{card['held_out_clips']} clips held out by a hash of the clip id (the priors' split); every clip the "
        "video benchmark renders left out.",
        f"- {card['steps']} AdamW steps of {cfg['batch_size']} windows of {cfg['frames']} frames, learning rate "
        f"{cfg['lr']:g} with cosine decay, dropout {cfg.get('dropout', 0.3):g}, teacher noise "
        f"{cfg['teacher_noise']:g}, scheduled sampling {cfg['sampling_passes']} passes up to "
        f"{cfg['sampling_prob']:g}, contact weight {cfg['contact_weight']:g}, seed {cfg['seed']}, one thread.",
        f"- Command: `{card['command']}`",
        *([f"- {card['note']}"] if card.get("note") else []),
        "",
        "## Held-out figures",
        "",
        "Windows of held-out clips through virtual cameras (a fixed seed), the network run autoregressively "
        "from a noisy initial state as at inference. PA-MPJPE: the camera-frame pose's 24 joints at zero betas; "
        "root velocity: the world velocity error R_root[t-1] v[t]; root orientation: the world root's angle "
        "error. Baselines: the initial pose held (and the training mean pose), zero and mean velocity with the "
        "initial orientation held, contacts always on.",
        "",
        "| held-out set | windows | PA-MPJPE mm (initial pose held / mean pose) | root velocity m/s (zero / "
        "mean) | root orientation deg (held) | contact F1 (always) |",
        "|---|---|---|---|---|---|",
    ]
    for name, f in (("every held-out clip", card["held_out_all"]),
                    (f"shipped sample ({card['sample']['clips']} CMU clips, regressor_sample.npz)",
                     card["sample"])):
        r, b = f["regressor"], f["baselines"]
        lines.append(f"| {name} | {f['windows']} | {r['pa_mpjpe_mm']:.1f} ({b['init_pose_pa_mpjpe_mm']:.1f} / "
                     f"{b['mean_pose_pa_mpjpe_mm']:.1f}) | {r['velocity_mps']:.3f} ({b['zero_velocity_mps']:.3f}"
                     f" / {b['mean_velocity_mps']:.3f}) | {r['root_deg']:.1f} ({b['held_root_deg']:.1f}) | "
                     f"{r['contact_f1']:.3f} ({b['always_contact_f1']:.3f}) |")
    lines += ["", "tests/python/test_shipped_regressor.py checks the shipped sample's figures.", ""]
    return "\n".join(lines)


def write_model_card(dest: Path) -> None:
    """MODEL_CARD.md from the figures of the weights shipped in dest."""
    parts = []
    for name, render in (("pose_prior.json", model_card), ("motion_prior.json", motion_model_card),
                         ("regressor.json", regressor_model_card)):
        if (dest / name).is_file():
            parts.append(render(json.loads((dest / name).read_text())))
    with atomic_path(dest / "MODEL_CARD.md") as tmp:
        tmp.write_text("\n".join(parts))


def motion_model_card(card: dict) -> str:
    cfg = card["config"]
    held, sample = card["held_out_all"], card["sample"]
    cm = lambda v: "-" if v is None else f"{v:.1f}"
    lines = [
        "# M3C motion prior (`motion_prior.pt`)",
        "",
        f"HuMoR's conditional VAE (posterior encoder, conditional prior, decoder with 9 contact outputs; "
        f"GroupNorm MLPs at {cfg['hidden']} hidden units, HuMoR's own is 1024; 48-d latent) over HuMoR's 339-d "
        "state, trained by M3C on the same corpus as the pose prior. Two departures from HuMoR, both in "
        "`m3c.training.motion_prior.MotionPrior`: the states are normalised by the training set's statistics "
        "(folded exactly into the first layer when exported, so the C++ motion term runs the encoder and prior "
        "unchanged), and the decoder predicts the change's departure from constant velocity.",
        "",
        "**Licence: non-commercial** (CC BY-NC 4.0, inherited from the Bandai Namco Research Motiondatasets), as "
        "the pose prior's.",
        "",
        "## Training",
        "",
        f"- {card['train_clips']} training clips, {card['train_pairs']} consecutive state pairs at 30 fps; "
        f"{card['held_out_clips']} clips held out by a hash of the clip id (the pose prior's split).",
        f"- {card['steps']} AdamW steps of {cfg['batch_size']} pairs, learning rate {cfg['lr']:g} with cosine "
        f"decay, KL weight {cfg['kl_weight']:g} (rising from 0 over the first {100 * cfg['kl_warmup']:.0f}% of "
        f"the steps), contact weight {cfg['contact_weight']:g}, seed {cfg['seed']}, one thread.",
        f"- Command: `{card['command']}`",
        *([f"- {card['note']}"] if card.get("note") else []),
        "",
        "## Held-out figures",
        "",
        "One step: the next state's 22 joints predicted by the decoder at the conditional prior's mean latent, "
        "against constant velocity (joints + velocity / 30 s), mean joint error. Rollouts: samples drawn from "
        "the conditional prior for 2 s from held-out states; sliding is the horizontal travel of an ankle or "
        "toe over each phase the prior calls planted (contact probability > 0.5, 3 frames or more); the same "
        "figure on the held-out mocap itself (planted by its contact labels) is the floor.",
        "",
        "| held-out set | pairs | prior mm | constant velocity mm | rollouts | sliding cm median (mocap) | "
        "lowest foot cm | on the ground |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, f in (("every held-out clip", {"one_step": held["held_out_one_step"],
                                              "rollouts": held["held_out_rollouts"],
                                              "truth_sliding": held["held_out_truth_sliding"]}),
                    (f"shipped sample ({sample['clips']} CMU clips, motion_prior_sample.npz)", sample)):
        o, r, t = f["one_step"], f["rollouts"], f["truth_sliding"]
        lines.append(f"| {name} | {o['pairs']} | {o['motion_prior_mm']:.2f} | {o['constant_velocity_mm']:.2f} | "
                     f"{r['samples']} | {cm(r['sliding_cm_median'])} ({cm(t['sliding_cm_median'])}) | "
                     f"{r['lowest_foot_cm_median']:.1f} | {100 * r['frames_on_ground']:.0f}% |")
    slide = held["held_out_rollouts"]["sliding_cm_median"]
    if slide is not None and slide > 2.0:
        lines += ["", "**Limit:** its own 2 s rollouts drift: planted feet slide "
                  f"{slide:.0f} "
                  "cm per planted phase (the mocap itself about 1 cm; the aim is under 2 cm) and the feet leave the "
                  "floor. One-step prediction, which the optimizer's transition term rests on, beats constant "
                  "velocity."]
    lines += ["", "tests/python/test_shipped_motion_prior.py checks the shipped sample's figures.", ""]
    return "\n".join(lines)


def model_card(card: dict) -> str:
    """The pose prior's section of MODEL_CARD.md from its figures."""
    cfg = card["config"]
    held, cmu, sample = card["held_out_all"], card["held_out_cmu"], card["sample"]
    lines = [
        "# M3C pose prior (`vposer_v2.ckpt`)",
        "",
        "VPoser v2's architecture (encoder BN-Linear-LReLU-BN-Dropout-Linear-Linear to a 32-d Gaussian, "
        "decoder "
        "to 21 rotations through the 6D representation; 512 hidden units), trained by M3C on open motion "
        "capture "
        "retargeted onto M3C's open body model (`m3c data mocap`). The official VPoser loader reads it: "
        "`m3c.models.vposer.load_vposer(path, version=\"v2\")`.",
        "",
        "**Licence: non-commercial.** The training data include the Bandai Namco Research Motiondatasets 1 "
        "and 2 "
        "(CC BY-NC 4.0), so these weights are for non-commercial use only (CC BY-NC 4.0). The CMU part: "
        "\"The data "
        "used in this project was obtained from mocap.cs.cmu.edu. The database was created with funding "
        "from NSF "
        "EIA-0196217.\"",
        "",
        "## Training",
        "",
        f"- Corpus: ../shared/data/mocap_corpus (Bandai Namco datasets 1 and 2, CMU subsets), every clip "
        f"the video "
        f"benchmark renders left out; {card['train_clips']} training clips, {card['train_frames']} frames "
        f"at 30 fps "
        f"(and their left-right mirror images); {card['held_out_clips']} clips held out by a hash of the "
        f"clip id.",
        f"- {card['steps']} AdamW steps of {cfg['batch_size']} poses, learning rate {cfg['lr']:g} with "
        f"cosine decay, "
        f"KL weight {cfg['kl_weight']:g}, joint weight {cfg['joint_weight']:g}, seed {cfg['seed']}, one "
        f"thread.",
        f"- Command: `{card['command']}`",
        *([f"- {card['note']}"] if card.get("note") else []),
        "",
        "## Held-out figures",
        "",
        "Encode (posterior mean) then decode; errors of the 21 body-joint rotations (degrees) and of the 24 "
        "joint "
        "positions (mm, the open model's rest skeleton at zero betas, root fixed). Baseline: a Gaussian "
        "over the "
        "63 axis-angle numbers fitted on the same training poses, reconstructing through its top 32 "
        "principal "
        "components (VPoser's latent size).",
        "",
        "| held-out set | poses | prior: joints mm / rotations deg | Gaussian (PCA-32): joints mm / "
        "rotations deg |",
        "|---|---|---|---|",
    ]
    for name, figures in (("every held-out clip", held), ("held-out CMU clips", cmu),
                          ("shipped sample (pose_prior_sample.npz)", sample)):
        poses = figures.get("held_out_poses", figures.get("poses", ""))
        v, g = figures["vposer"], figures["gaussian_pca32"]
        lines.append(f"| {name} | {poses} | {v['joint_mm']:.1f} / {v['rotation_deg']:.2f} | "
                     f"{g['joint_mm']:.1f} / {g['rotation_deg']:.2f} |")
    lines += ["", "tests/python/test_shipped_pose_prior.py checks the shipped sample's figures.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("corpus_dir", type=Path)
    parser.add_argument("--dest", type=Path,
                        default=Path(__file__).resolve().parents[1] / "models" / "weights")
    parser.add_argument("--command", default="", help="the training command, for the card")
    parser.add_argument("--eval-corpus", type=Path, help="corpus whose held-out split is measured")
    parser.add_argument("--note", default="", help="a remark for the card's training section")
    parser.add_argument("--motion", action="store_true", help="ship a motion prior (m3c train motion-prior)")
    parser.add_argument("--regressor", action="store_true", help="ship a world regressor (m3c train regressor)")
    args = parser.parse_args(argv)
    if args.regressor:
        card = ship_regressor(args.run_dir, args.corpus_dir, args.dest, args.command, args.note)
        print(json.dumps({k: card[k] for k in ("held_out_all", "sample")}, indent=1))
        return 0
    if args.motion:
        card = ship_motion_prior(args.run_dir, args.corpus_dir, args.dest, args.command, args.note)
        print(json.dumps({k: card[k] for k in ("held_out_all", "sample")}, indent=1))
        return 0
    card = ship(args.run_dir, args.corpus_dir, args.dest, args.command, args.eval_corpus, args.note)
    print(json.dumps({k: card[k] for k in ("held_out_all", "held_out_cmu", "sample")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
