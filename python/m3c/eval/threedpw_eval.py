"""Evaluating prediction files on 3DPW (thesis 5.3): per method, per sequence, the thesis's tables.

Ground truth: every person of every sequence file of a split, on the frames whose camera pose is valid
(campose_valid), posed by the gendered SMPL models from the dataset's parameters (thesis 5.2.4).
Predictions: one file per sequence, `<results dir>/<sequence name>.npz`, holding per track k
    track{k}_frames        (n,) frame ids (0-based image frames of the sequence)
    track{k}_root_orient   (n, 3) world-frame axis-angle     track{k}_transl (n, 3) world-frame metres
    track{k}_body_pose     (n, 23, 3) or (n, 69)              track{k}_betas  (10,) or (n, 10)
and, for the sequence, `world_from_cam` (T, 4, 4) of the method's own cameras (camera-frame metrics pose the
world-frame bodies in these cameras; a camera-local method writes its local bodies with identity cameras).
An `m3c run` output folder `<results dir>/<sequence name>/` (results.npz) is read as well (read_m3c_results).
Predictions are posed by the neutral SMPL model. Joints: the 14 evaluation joints from the H36M regressor
(J_regressor_h36m, 17 x 6890, which users bring) with pelvis = mean of J14 rows 2 and 3; without it, SMPL's 24
joints with pelvis = mean of the hips (not comparable with published 3DPW numbers).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.body import BodyModel
from m3c.body.joint_names import J14_PELVIS
from m3c.eval.datasets.threedpw import ThreeDPWSequence, list_sequences, read_sequence
from m3c.eval.evaluate import (METRICS, SequenceResult, aggregate, evaluate_sequence, format_method_table,
                               format_value)
from m3c.eval.tracks import EvalTrack, body_eval_track

_TRACK_KEY = re.compile(r"track(\d+)_frames$")


@dataclass
class PredictedTrack:
    frames: np.ndarray
    root_orient: np.ndarray
    body_pose: np.ndarray
    betas: np.ndarray
    transl: np.ndarray


def read_predictions(path: str | Path) -> tuple[list[PredictedTrack], np.ndarray]:
    """(tracks, world_from_cam (T, 4, 4)) of one prediction file in the layout above."""
    path = Path(path)
    with np.load(path) as z:
        if "world_from_cam" not in z.files:
            raise ValueError(f"{path}: missing world_from_cam (T, 4, 4), the method's cameras")
        world_from_cam = np.asarray(z["world_from_cam"], dtype=np.float64)
        ids = sorted(int(m.group(1)) for m in map(_TRACK_KEY.match, z.files) if m)
        tracks = []
        for k in ids:
            keys = [f"track{k}_{f}" for f in ("frames", "root_orient", "body_pose", "betas", "transl")]
            missing = [key for key in keys if key not in z.files]
            if missing:
                raise ValueError(f"{path}: track {k} lacks {missing}")
            frames = np.asarray(z[keys[0]], dtype=np.int64).reshape(-1)
            n = len(frames)
            betas = np.asarray(z[keys[3]], dtype=np.float64)
            tracks.append(PredictedTrack(frames, np.asarray(z[keys[1]], np.float64).reshape(n, 3),
                                         np.asarray(z[keys[2]], np.float64).reshape(n, 23, 3),
                                         betas if betas.ndim == 1 else betas.reshape(n, -1),
                                         np.asarray(z[keys[4]], np.float64).reshape(n, 3)))
    if world_from_cam.ndim != 3 or world_from_cam.shape[1:] != (4, 4):
        raise ValueError(f"{path}: world_from_cam must have shape (T, 4, 4), got {world_from_cam.shape}")
    for k, tr in enumerate(tracks):
        if tr.frames.max(initial=-1) >= len(world_from_cam) or tr.frames.min(initial=0) < 0:
            raise ValueError(f"{path}: track {k} has frames outside the {len(world_from_cam)} cameras")
    return tracks, world_from_cam


def read_m3c_results(folder: str | Path) -> tuple[list[PredictedTrack], np.ndarray]:
    """(tracks, world_from_cam) from an `m3c run` output folder, in read_predictions' form: track frames are
    the video's frame ids, and world_from_cam covers frames 0 .. last processed (frames skipped by a frame step
    take the previous processed camera)."""
    from m3c.io.results import load_results

    _, r = load_results(folder)
    frame_ids = np.asarray(r["frame_ids"], dtype=np.int64)
    cams = np.asarray(r["world_from_cam"], dtype=np.float64)
    index = np.searchsorted(frame_ids, np.arange(frame_ids[-1] + 1), side="right") - 1
    world_from_cam = cams[np.maximum(index, 0)]
    tracks = []
    for p in range(len(r["track_ids"])):
        valid = np.asarray(r["valid"][p], dtype=bool)
        if not valid.any():
            continue
        tracks.append(PredictedTrack(frame_ids[valid], np.asarray(r["world_root_orient"][p][valid], np.float64),
                                     np.asarray(r["body_pose"][p][valid], np.float64),
                                     np.asarray(r["betas"][p], np.float64),
                                     np.asarray(r["world_transl"][p][valid], np.float64)))
    return tracks, world_from_cam


def _eval_regressor(model: BodyModel, j_regressor_h36m):
    return None if j_regressor_h36m is None else model.h36m_regressor(j_regressor_h36m, evaluation_joints=True)


def ground_truth_tracks(seq: ThreeDPWSequence, models: dict[str, BodyModel], j_regressor_h36m=None
                        ) -> list[EvalTrack]:
    """Every person on its valid frames, posed by the gendered model in the world and the dataset's
    cameras."""
    world_from_cam = seq.world_from_cam
    out = []
    for person in seq.people:
        model = models[person.gender]
        frames = np.flatnonzero(person.valid)
        out.append(body_eval_track(model, frames, person.root_orient[frames], person.body_pose[frames],
                                   person.betas, person.transl[frames], world_from_cam[frames],
                                   _eval_regressor(model, j_regressor_h36m)))
    return out


def prediction_tracks(tracks: list[PredictedTrack], world_from_cam, model: BodyModel, j_regressor_h36m=None
                      ) -> list[EvalTrack]:
    reg = _eval_regressor(model, j_regressor_h36m)
    return [body_eval_track(model, t.frames, t.root_orient, t.body_pose, t.betas, t.transl,
                            world_from_cam[t.frames], reg) for t in tracks]


def evaluate_3dpw(root: str | Path, split: str, results: dict[str, str | Path], models: dict[str, BodyModel],
                  j_regressor_h36m=None, sequences: list[str] | None = None, log=None) -> dict:
    """results: method name -> folder of prediction files. models: "male", "female", "neutral" BodyModels.
    Returns {"methods": {method: {metric: mean}}, "sequences": {name: {"people": n, method: SequenceResult}}}.
    A sequence without a prediction file for a method counts all its people as missed for that method."""
    missing = {"male", "female", "neutral"} - set(models)
    if missing:
        raise ValueError(f"models must include {sorted(missing)} (SMPL files the user brings)")
    pelvis = J14_PELVIS if j_regressor_h36m is not None else (1, 2)
    per_method: dict[str, list[SequenceResult]] = {m: [] for m in results}
    table: dict[str, dict] = {}
    for path in list_sequences(root, split):
        seq = read_sequence(path, split)
        if sequences and seq.name not in sequences:
            continue
        gt = ground_truth_tracks(seq, models, j_regressor_h36m)
        table[seq.name] = {"people": len(gt)}
        for method, folder in results.items():
            pred_path = Path(folder) / f"{seq.name}.npz"
            run_folder = Path(folder) / seq.name
            if pred_path.is_file() or (run_folder / "results.npz").is_file():
                tracks, cams = read_predictions(pred_path) if pred_path.is_file() else read_m3c_results(run_folder)
                pred = prediction_tracks(tracks, cams, models["neutral"], j_regressor_h36m)
            else:
                pred = []
            result = evaluate_sequence(gt, pred, seq.fps, pelvis, seq.name)
            per_method[method].append(result)
            table[seq.name][method] = result
        if log:
            log(f"{seq.name}: " + ", ".join(
                f"{m} PA-MPJPE {format_value('pa_mpjpe', table[seq.name][m].mean('pa_mpjpe')).strip()}"
                for m in results))
    return {"methods": {m: aggregate(r) for m, r in per_method.items()}, "sequences": table,
            "joints": "H36M-14" if j_regressor_h36m is not None else "SMPL-24"}


def format_3dpw_tables(evaluation: dict) -> str:
    methods = list(evaluation["methods"])
    lines = [f"3DPW ({evaluation['joints']} joints; mm unless stated)", "",
             format_method_table(evaluation["methods"], tuple(METRICS)[:4] + tuple(METRICS)[4:]), ""]
    name_w = max([12] + [len(n) + 3 for n in evaluation["sequences"]])
    head = "Scene".ljust(name_w) + "".join(f"{m + ': PA-MPJPE':>24}{'MPJPE':>9}" for m in methods)
    lines += [head, "-" * len(head)]
    for name, row in evaluation["sequences"].items():
        text = f"{name}^{row['people']}".ljust(name_w)
        for m in methods:
            r = row[m]
            text += format_value("pa_mpjpe", r.mean("pa_mpjpe"), 24, 2)
            text += format_value("mpjpe", r.mean("mpjpe"), 9, 2)
        lines.append(text)
    return "\n".join(lines)
