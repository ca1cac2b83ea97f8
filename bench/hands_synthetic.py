#!/usr/bin/env python3
"""The hand pipeline on rendered hands: the open model's left hand posed from random finger poses (uniform
within a fraction of the joint limits), rendered close up (m3c.synth.hands), MediaPipe Hands on the wrist
crop, then the per-frame fit. Reports the detection rate, the per-finger-joint error after Procrustes on the
hand (the 15 SMPL-H finger joints, similarity-aligned on the hand's 21 points) against the rest hand as a
baseline, and the seconds per frame of detection and fit.

    PYTHONPATH=python python3 bench/hands_synthetic.py [--poses 20] [--spread 0.6] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from m3c.body import BodyModel, open_body_model_data
from m3c.body.hands import MEDIAPIPE_FROM_HAND, load_hand_model
from m3c.perception.hand_fit import LOWER, NUM_DOFS, UPPER, SideModel, fit_hand
from m3c.perception.hands import MediaPipeHands, detect_hands
from m3c.synth.hands import render_hand_scene
from scipy.spatial.transform import Rotation

# Rows of the 21 MediaPipe points that are SMPL-H finger joints (not the wrist, not the tips).
FINGER_JOINT_ROWS = [row for row, source in enumerate(MEDIAPIPE_FROM_HAND) if 1 <= source <= 15]


def procrustes(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """estimate similarity-aligned onto truth (both N x 3)."""
    a, b = estimate - estimate.mean(axis=0), truth - truth.mean(axis=0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return (np.sum(S * np.diag(D)) / np.sum(a * a)) * a @ R.T + truth.mean(axis=0)


def main(argv=None) -> int:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=20)
    parser.add_argument("--spread", type=float, default=0.6, help="fraction of the joint limits sampled")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args(argv)
    model = BodyModel(open_body_model_data())
    hand = load_hand_model()
    engine = MediaPipeHands()
    side = SideModel(hand, np.zeros(model.num_betas), "left")
    rng = np.random.default_rng(args.seed)
    detect_s, fit_s, errors, baseline, found, wrong = [], [], [], [], 0, 0
    for _ in range(args.poses):
        dofs = rng.uniform(args.spread * LOWER, args.spread * UPPER)
        view = np.array([0.2, -1.0, 0.6]) + rng.normal(0, 0.2, 3)
        scene = render_hand_scene(model, dofs, view=view, hand=hand)
        rgb = cv2.cvtColor(scene.image, cv2.COLOR_BGR2RGB)
        start = time.perf_counter()
        landmarks = detect_hands(engine, rgb, scene.keypoints)
        detect_s.append(time.perf_counter() - start)
        truth = scene.hand_keypoints_in_world[0]
        rest = side.landmarks(np.zeros((1, NUM_DOFS)), scene.wrist_rotation[0][None],
                              scene.wrist_position[0])[0]
        baseline.append(np.linalg.norm(procrustes(rest, truth) - truth, axis=1)[FINGER_JOINT_ROWS].mean())
        if not np.isfinite(landmarks[0, 0, 0]):
            continue
        found += 1
        if np.isfinite(landmarks[1, 0, 0]):
            wrong += 1  # the right hand is out of view: a right-hand detection is wrong
        start = time.perf_counter()
        fit = fit_hand(side, landmarks[0], scene.wrist_rotation[0], scene.wrist_position[0],
                       scene.world_from_cam, scene.intrinsics)
        fit_s.append(time.perf_counter() - start)
        if fit is None:
            continue
        wrist = scene.wrist_rotation[0] @ Rotation.from_rotvec(fit.wrist_correction).as_matrix()
        estimate = side.landmarks(fit.dofs[None], wrist[None], scene.wrist_position[0])[0]
        errors.append(np.linalg.norm(procrustes(estimate, truth) - truth, axis=1)[FINGER_JOINT_ROWS].mean())
    engine.close()
    figures = {
        "poses": args.poses, "spread": args.spread, "detected": found, "wrong_side_detections": wrong,
        "pa_finger_joint_error_mm": 1000 * float(np.mean(errors)) if errors else None,
        "pa_finger_joint_error_median_mm": 1000 * float(np.median(errors)) if errors else None,
        "rest_hand_pa_error_mm": 1000 * float(np.mean(baseline)),
        "detect_s_per_frame": float(np.mean(detect_s)),
        "fit_s_per_hand": float(np.mean(fit_s)) if fit_s else None,
    }
    report(figures, args.json)
    return 0


def report(figures: dict, path: str | None) -> None:
    """The figures on stdout and, written whole or not at all, in path (the benchmarks' --json)."""
    from m3c.io.atomic import atomic_path

    text = json.dumps(figures, indent=1)
    print(text)
    if path:
        with atomic_path(path) as tmp:
            tmp.write_text(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
