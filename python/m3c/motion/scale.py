"""The camera scale of world-frame tracks (the optimizer's input) by M3C's one scale estimator (m3c.vo.scale),
for callers that start from lifted tracks rather than camera-local ones (the benchmarks, scripts)."""

from __future__ import annotations

import dataclasses

import numpy as np

from m3c.body import BodyModel
from m3c.motion.optimize import CONTACT_JOINTS, Cameras, Track, track_joints
from m3c.vo.scale import ScaleEstimate, fuse, scale_from_planted_feet


def estimate_scale(model: BodyModel, tracks: list[Track], cameras: Cameras, contact_threshold: float = 0.5
                   ) -> ScaleEstimate:
    """The planted-feet estimate of the camera scale from tracks lifted with cameras.world_from_cam at
    cameras.initial_scale (their camera-relative positions are the camera-local evidence). Static cameras and
    tracks without contacts give the estimator's default (sigma None)."""
    if cameras.static:
        return ScaleEstimate(float(cameras.initial_scale), None, "static camera")
    vo = np.asarray(cameras.world_from_cam, dtype=np.float64)
    joints_cam, planted, frames = [], [], []
    for track in tracks:
        if track.contacts is None:
            continue
        idx = track.first_frame + np.arange(track.num_frames)
        world = track_joints(model, track)[:, list(CONTACT_JOINTS)]
        centres = cameras.initial_scale * vo[idx, :3, 3]
        joints_cam.append(np.einsum("nji,nkj->nki", vo[idx, :3, :3], world - centres[:, None]))
        planted.append(np.asarray(track.contacts) >= contact_threshold)
        frames.append(idx)
    return fuse([scale_from_planted_feet(joints_cam, planted, frames, vo)], default=cameras.initial_scale)


def rescaled(tracks: list[Track], cameras: Cameras, estimate: ScaleEstimate) -> tuple[list[Track], Cameras]:
    """The tracks and cameras at the estimated scale: every person keeps its position relative to its camera
    (translations move with the camera centres), the cameras carry the estimate's value and uncertainty."""
    vo = np.asarray(cameras.world_from_cam, dtype=np.float64)
    shift = estimate.value - cameras.initial_scale
    out = [dataclasses.replace(t, transl=np.asarray(t.transl) + shift * vo[t.first_frame:t.first_frame + t.num_frames,
                                                                           :3, 3])
           for t in tracks]
    return out, dataclasses.replace(cameras, initial_scale=estimate.value, scale_sigma=estimate.sigma)
