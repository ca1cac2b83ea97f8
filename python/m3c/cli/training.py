"""`m3c train pose-prior|motion-prior|regressor`: M3C's own priors and world regressor, trained on a corpus of
`m3c data mocap`."""

from __future__ import annotations

import json

from m3c.cli.common import log_to_stderr, output_folder


def _threads(args) -> None:
    import torch

    if args.threads < 1:
        raise ValueError(f"--threads must be at least 1, got {args.threads}")
    torch.set_num_threads(args.threads)


def _prepare(args, config):
    """What both commands do before training: threads, the output folder, the config's bounds, the body model,
    the log and the corpus's training and held-out clips."""
    from m3c.body import default_body_model
    from m3c.mocap.corpus import load_corpus

    _threads(args)
    out = output_folder(args.out)
    if config.steps < 1 or config.batch_size < 1:
        raise ValueError("--steps and --batch-size must be positive")
    model = default_body_model(args.body_model)
    log = None if args.quiet else log_to_stderr
    return out, model, log, load_corpus(args.corpus, "train"), load_corpus(args.corpus, "held_out")


def _write_metrics(out, report: dict) -> None:
    from m3c.io.atomic import atomic_path

    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1) + "\n")


def train_pose_prior_command(args) -> int:
    from m3c.models.vposer import load_vposer
    from m3c.training.common import JointKinematics
    from m3c.training.pose_prior import PosePriorConfig, body_poses, evaluate_pose_prior, train_pose_prior

    config = PosePriorConfig(steps=args.steps, batch_size=args.batch_size, lr=args.lr,
                             kl_weight=args.kl_weight, seed=args.seed,
                             checkpoint_minutes=args.checkpoint_minutes, mirror=not args.no_mirror)
    out, model, log, train_clips, held_clips = _prepare(args, config)
    train = body_poses(train_clips, config.mirror)
    if log:
        log(f"pose prior: {len(train_clips)} training clips, {len(train)} poses (mirrored: {config.mirror}); "
            f"{len(held_clips)} held-out clips")
    summary = train_pose_prior(train, out, model, config, resume=args.resume, log=log)
    vposer = load_vposer(out / "vposer_v2.ckpt", version="v2")
    report = {"corpus": str(args.corpus), "train_clips": len(train_clips), "train_frames":
              int(sum(len(c["pose"]) for c in train_clips)), "held_out_clips": len(held_clips),
              "steps": summary["steps_done"],
              "final_loss": summary["history"][-1] if summary["history"] else None}
    if held_clips:
        held = body_poses(held_clips, mirror=False)
        report["held_out"] = evaluate_pose_prior(vposer, train, held, JointKinematics.from_model(model))
    _write_metrics(out, report)
    print(f"wrote {out}/vposer_v2.ckpt ({summary['steps_done']} steps)")
    if "held_out" in report:
        for name, row in report["held_out"].items():
            if isinstance(row, dict):
                print(f"  held out ({report['held_out']['held_out_poses']} poses) {name}: "
                      f"{row['joint_mm']:.1f} mm, {row['rotation_deg']:.2f} deg")
    return 0


ROLLOUTS = 64  # samples from the motion prior rolled out from held-out states


def train_motion_prior_command(args) -> int:
    from m3c.training.motion_prior import (MotionPriorConfig, load_motion_prior, one_step_errors, pairs,
                                           rollout_figures, start_states, train_motion_prior,
                                           train_motion_prior_rollouts, truth_sliding, windows)

    config = MotionPriorConfig(steps=args.steps, batch_size=args.batch_size, lr=args.lr, hidden=args.hidden,
                               kl_weight=args.kl_weight, seed=args.seed,
                               checkpoint_minutes=args.checkpoint_minutes, rollout_steps=args.rollout_steps,
                               # fine-tuning a trained prior: its KL weight in full from the start
                               kl_warmup=0.0 if args.init else MotionPriorConfig.kl_warmup)
    if config.rollout_steps < 1:
        raise ValueError(f"--rollout-steps must be at least 1, got {config.rollout_steps}")
    out, model, log, train_clips, held_clips = _prepare(args, config)
    if config.rollout_steps == 1:
        if args.init:
            raise ValueError("--init goes with --rollout-steps > 1 (fine-tuning a prior on its own rollouts)")
        data = pairs(train_clips, model, config)
        transitions = len(data[0])
        if log:
            log(f"motion prior: {len(train_clips)} training clips, {transitions} state pairs; "
                f"{len(held_clips)} held-out clips")
        summary = train_motion_prior(data, out, config, resume=args.resume, log=log)
    else:
        data = windows(train_clips, model, config)
        transitions = len(data[0]) * config.rollout_steps
        if log:
            log(f"motion prior: {len(train_clips)} training clips, {len(data[0])} windows of "
                f"{config.rollout_steps} transitions; {len(held_clips)} held-out clips")
        summary = train_motion_prior_rollouts(data, out, config, init=args.init, resume=args.resume, log=log)
    report = {"corpus": str(args.corpus), "train_clips": len(train_clips), "train_pairs": transitions,
              "held_out_clips": len(held_clips), "steps": summary["steps_done"], "init": args.init}
    if held_clips:
        held = pairs(held_clips, model, config)
        prior = load_motion_prior(out / "motion_prior.pt")
        report["held_out_one_step"] = one_step_errors(prior, held[0], held[1])
        starts = start_states(held_clips, model, config, count=ROLLOUTS, seed=config.seed)
        report["held_out_rollouts"] = rollout_figures(prior, starts, seconds=2.0, seed=config.seed)
        report["held_out_truth_sliding"] = truth_sliding(held_clips, model, config)
    _write_metrics(out, report)
    print(f"wrote {out}/motion_prior.pt ({summary['steps_done']} steps)")
    if "held_out_one_step" in report:
        r = report["held_out_one_step"]
        print(f"  held out ({r['pairs']} pairs), next-frame joints: motion prior {r['motion_prior_mm']:.1f} "
              "mm, "
              f"constant velocity {r['constant_velocity_mm']:.1f} mm")
        r, t = report["held_out_rollouts"], report["held_out_truth_sliding"]
        slide = lambda v: "-" if v is None else f"{v:.1f}"
        print(f"  {r['samples']} samples rolled out {r['seconds']:.0f} s: planted feet slide "
              f"{slide(r['sliding_cm_median'])} cm median per planted phase ({r['planted_phases']} phases; the "
              f"held-out mocap itself {slide(t['sliding_cm_median'])}), lowest foot "
              f"{r['lowest_foot_cm_median']:.1f} cm above the floor, on the ground {100 * r['frames_on_ground']:.0f}%"
              " of frames")
    return 0


def train_regressor_command(args) -> int:
    from m3c.training.common import JointKinematics
    from m3c.training.regressor import (RegressorConfig, evaluate, evaluation_batch, load_regressor,
                                        mean_training_targets, prepare_clips, train_regressor)

    config = RegressorConfig(steps=args.steps, batch_size=args.batch_size, frames=args.frames,
                             width=args.width, lr=args.lr, teacher_noise=args.teacher_noise, seed=args.seed,
                             checkpoint_minutes=args.checkpoint_minutes, root=args.root,
                             sampling_passes=args.sampling_passes, sampling_prob=args.sampling_prob,
                             dropout=args.dropout, contact_weight=args.contact_weight,
                             root_noise=args.root_noise)
    if config.frames < 2 or config.width < 1:
        raise ValueError("--frames must be at least 2 and --width positive")
    if config.sampling_passes < 0 or not 0.0 <= config.sampling_prob <= 1.0:
        raise ValueError("--sampling-passes must be at least 0 and --sampling-prob in [0, 1]")
    out, model, log, train_clips, held_clips = _prepare(args, config)
    train = prepare_clips(train_clips, model, config.frames)
    if log:
        log(f"regressor: {len(train)} training clips of at least {config.frames + 1} frames; "
            f"{len(held_clips)} held-out clips")
    summary = train_regressor(train, out, model, config, resume=args.resume, log=log, minutes=args.minutes,
                              init=args.init)
    report = {"corpus": str(args.corpus), "train_clips": len(train), "held_out_clips": len(held_clips),
              "steps": summary["steps_done"], "of_steps": config.steps,
              "final_loss": summary["history"][-1] if summary["history"] else None}
    if held_clips:
        held = prepare_clips(held_clips, model, config.frames)
        batch = evaluation_batch(held, config, windows=args.eval_windows)
        report["held_out"] = evaluate(load_regressor(out / "regressor.pt"), batch,
                                      JointKinematics.from_model(model), mean_training_targets(train, config))
    _write_metrics(out, report)
    print(f"wrote {out}/regressor.pt ({summary['steps_done']} of {config.steps} steps)")
    if "held_out" in report:
        r, b = report["held_out"]["regressor"], report["held_out"]["baselines"]
        print(f"  held out ({report['held_out']['windows']} windows of {config.frames} frames): PA-MPJPE "
              f"{r['pa_mpjpe_mm']:.1f} mm (mean pose {b['mean_pose_pa_mpjpe_mm']:.1f}, initial pose held "
              f"{b['init_pose_pa_mpjpe_mm']:.1f}); root velocity {r['velocity_mps']:.3f} m/s (zero "
              f"{b['zero_velocity_mps']:.3f}, mean {b['mean_velocity_mps']:.3f}); root orientation "
              f"{r['root_deg']:.1f} deg (held {b['held_root_deg']:.1f}); contact F1 {r['contact_f1']:.3f} "
              f"(always {b['always_contact_f1']:.3f})")
    return 0
