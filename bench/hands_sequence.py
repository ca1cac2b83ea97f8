#!/usr/bin/env python3
"""The hands over time on rendered hands: the open model's left hand moving smoothly between random finger
poses (uniform within a fraction of the joint limits) over --frames frames, rendered close up
(m3c.synth.hands) from a slowly moving camera, MediaPipe Hands on every frame, then (a) the per-frame fit
smoothed by a Gaussian (the hands node before the track solve) and (b) the track solve
(m3c.perception.hand_track) started from the per-frame fits. Reports, over the frames with a detection, the
per-finger-joint error after Procrustes on the hand (the 15 SMPL-H finger joints, similarity-aligned on the
hand's 21 points), the finger joints' jitter (mean |second difference| of their world positions, mm per
frame^2, the truth's own for reference), and the seconds of each solve.

    PYTHONPATH=python python3 bench/hands_sequence.py [--sequences 3] [--frames 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np
from hands_synthetic import FINGER_JOINT_ROWS, procrustes, report
from m3c.body import BodyModel, open_body_model_data
from m3c.body.hands import load_hand_model
from m3c.perception.hand_fit import LOWER, NUM_DOFS, UPPER, SideModel, _rodrigues, fit_hand, smooth_dofs
from m3c.perception.hand_track import NUM_VARS, TrackWeights, fit_hand_track
from m3c.perception.hands import MediaPipeHands, detect_hands
from m3c.synth.hands import render_hand_scene


def main(argv=None) -> int:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", type=int, default=3)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--spread", type=float, default=0.6, help="fraction of the joint limits sampled")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--weights", default="", help="TrackWeights overrides, e.g. accel=4,velocity=1 "
                        "(several sets separated by ';' are each solved)")
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args(argv)
    settings = [dict((kv.split("=")[0], float(kv.split("=")[1])) for kv in group.split(",") if kv)
                for group in args.weights.split(";")]
    variants = {("track" if not w else "track " + ",".join(f"{k}={v:g}" for k, v in w.items())): w
                for w in settings}
    model = BodyModel(open_body_model_data())
    hand = load_hand_model()
    engine = MediaPipeHands()
    side = SideModel(hand, np.zeros(model.num_betas), "left")
    rng = np.random.default_rng(args.seed)
    errors = {"per_frame_smoothed": [], **{name: [] for name in variants}}
    jitter = {"per_frame_smoothed": [], **{name: [] for name in variants}, "truth": []}
    seconds = {"per_frame": 0.0, **{name: 0.0 for name in variants}}
    detected = total = 0
    for _ in range(args.sequences):
        a, b = rng.uniform(args.spread * LOWER, args.spread * UPPER, (2, NUM_DOFS))
        s = np.linspace(0.0, 1.0, args.frames)[:, None]
        truth_dofs = a + (b - a) * (0.5 - 0.5 * np.cos(np.pi * s))
        view0 = np.array([0.2, -1.0, 0.6]) + rng.normal(0, 0.15, 3)
        scenes, landmarks = [], np.full((args.frames, 21, 3), np.nan)
        for t in range(args.frames):
            scene = render_hand_scene(model, truth_dofs[t], view=view0 + np.array([0.004 * t, 0.0, 0.0]),
                                      hand=hand)
            scenes.append(scene)
            landmarks[t] = detect_hands(engine, cv2.cvtColor(scene.image, cv2.COLOR_BGR2RGB),
                                        scene.keypoints)[0]
        rotation = np.stack([sc.wrist_rotation[0] for sc in scenes])
        position = np.stack([sc.wrist_position[0] for sc in scenes])
        cams = np.stack([sc.world_from_cam for sc in scenes])
        K = scenes[0].intrinsics
        start = time.perf_counter()
        per_frame, previous = np.full((args.frames, NUM_VARS), np.nan), None
        for t in range(args.frames):
            fit = None
            if np.isfinite(landmarks[t, 0, 0]):
                fit = fit_hand(side, landmarks[t], rotation[t], position[t], cams[t], K, previous=previous)
            previous = fit
            if fit is not None:
                per_frame[t] = np.r_[fit.dofs, fit.wrist_correction]
        found = np.isfinite(per_frame[:, 0])
        smoothed = smooth_dofs(np.nan_to_num(per_frame), found, 1.5)
        seconds["per_frame"] += time.perf_counter() - start
        solved = {}
        for name, overrides in variants.items():
            start = time.perf_counter()
            solved[name] = fit_hand_track(side, landmarks, rotation, position, cams, K, per_frame,
                                          replace(TrackWeights(), **overrides))
            seconds[name] += time.perf_counter() - start
        detected += int(found.sum())
        total += args.frames
        truth = np.stack([sc.hand_keypoints_in_world[0] for sc in scenes])

        def world(values):
            out = np.full((args.frames, 21, 3), np.nan)
            for t in np.flatnonzero(np.isfinite(values[:, 0])):
                wrist = rotation[t] @ _rodrigues(values[t, NUM_DOFS:])
                out[t] = side.landmarks(values[t:t + 1, :NUM_DOFS], wrist[None], position[t])[0]
            return out
        for name, values in (("per_frame_smoothed", smoothed), *solved.items()):
            points = world(values)
            for t in np.flatnonzero(found):
                aligned = procrustes(points[t], truth[t])
                errors[name].append(np.linalg.norm(aligned - truth[t], axis=1)[FINGER_JOINT_ROWS].mean())
            both = found[2:] & found[1:-1] & found[:-2]
            acc = np.linalg.norm(points[2:] - 2 * points[1:-1] + points[:-2], axis=-1)[:, FINGER_JOINT_ROWS]
            jitter[name] += list(acc[both].mean(axis=1))
            if name == "per_frame_smoothed":
                acc = np.linalg.norm(truth[2:] - 2 * truth[1:-1] + truth[:-2], axis=-1)[:, FINGER_JOINT_ROWS]
                jitter["truth"] += list(acc[both].mean(axis=1))
    engine.close()
    figures = {
        "sequences": args.sequences, "frames": args.frames, "spread": args.spread,
        "detected_frames": detected, "of_frames": total,
        "pa_finger_joint_error_mm": {k: 1000 * float(np.mean(v)) for k, v in errors.items() if v},
        "finger_jitter_mm_per_frame2": {k: 1000 * float(np.mean(v)) for k, v in jitter.items() if v},
        "seconds_per_frame": {k: v / max(total, 1) for k, v in seconds.items()},
    }
    report(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
