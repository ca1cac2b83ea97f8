"""The camera scale of people's tracks by M3C's one scale estimator (m3c.vo.scale): estimate_camera_scale for
camera-local tracks (the pipeline's scale node), estimate_scale for tracks already lifted to the world (the
optimizer's input; the benchmarks, scripts)."""

from __future__ import annotations

import dataclasses

import numpy as np

from m3c.body import BodyModel
from m3c.ground.tracks import contact_vertices, ground_contact_probabilities, track_frames, track_poses
from m3c.ground.world_frame import body_up
from m3c.body.joint_names import CONTACT_JOINTS
from m3c.motion.optimize import Cameras, Track, track_joints
from m3c.eval.plausibility import PELVIS, leg_length, stride_frequency
from m3c.vo.scale import (PLAUSIBLE_CAMERA_HEIGHT_M, ScaleEstimate, ScaleObservation, fuse, map_ground_plane,
                          scale_from_camera_height, scale_from_depth, scale_from_gait, scale_from_planted_feet,
                          scale_subjects)


def contact_joints_in_camera(model, track: dict) -> np.ndarray:
    """(n, 4, 3) positions of the contact joints (ankles, feet) of a camera-frame track."""
    joints = model.joints(track_poses(track), track["betas"], track["transl"])
    return joints[:, list(CONTACT_JOINTS)]


def gait_observation(model, tracks: list[dict], world_from_cam: np.ndarray, up: np.ndarray,
                     fps: float | None) -> ScaleObservation:
    """The gait source (m3c.vo.scale.scale_from_gait) of camera-local tracks: each track's longest run of
    visible frames, its pelvis in the camera, its stride frequency from the feet's alternation seen in the VO
    frame's rotation (no scale needed) and its leg length."""
    if fps is None or not fps > 0:
        return ScaleObservation("gait", reason="no frame rate")
    pelvis, strides, legs, frames = [], [], [], []
    for track in tracks:
        visible = np.flatnonzero(track["visible"])
        if len(visible) < 8:
            continue
        runs = np.split(visible, np.flatnonzero(np.diff(visible) != 1) + 1)
        run = max(runs, key=len)
        idx = int(track["first_frame"]) + run
        joints = model.joints(track_poses(track)[run], track["betas"], np.asarray(track["transl"])[run])
        rotated = np.einsum("nij,nkj->nki", world_from_cam[idx, :3, :3], joints)
        pelvis.append(joints[:, list(PELVIS)].mean(axis=1))
        stride = stride_frequency(rotated, fps, np.tile(up, (len(run), 1)))
        strides.append(None if stride is None else stride / fps)
        legs.append(leg_length(joints))
        frames.append(idx)
    return scale_from_gait(pelvis, strides, legs, frames, world_from_cam, up)


def estimate_camera_scale(model, tracks: list[dict], cameras: dict, contact_threshold: float = 0.5,
                          depth: dict | None = None, intrinsics=None, log=None, fps: float | None = None
                          ) -> ScaleEstimate:
    """The camera scale from every observation that carries it (m3c.vo.scale): the planted feet against the
    camera's motion, the camera's height above the ground (contacts) against the map's ground, the people's steps
    against their legs (with the video's fps), and metric depth maps when given. cameras: the vo node's output
    (world_from_cam, points, static)."""
    vo = np.asarray(cameras["world_from_cam"], dtype=np.float64)
    observations = []
    up = body_up(model, tracks, vo) if tracks else np.zeros(3)  # every person stands upright, near or far
    feet_cam = [contact_joints_in_camera(model, t) for t in tracks]
    subject = scale_subjects([joints[np.asarray(t["visible"], bool), :, 2].mean(axis=1)
                              for t, joints in zip(tracks, feet_cam)])
    tracks = [t for t, keep in zip(tracks, subject) if keep]
    feet_cam = [joints for joints, keep in zip(feet_cam, subject) if keep]
    feet = scale_from_planted_feet(feet_cam,
                                   [(ground_contact_probabilities(t) >= contact_threshold) & t["visible"][:, None]
                                    if "contacts" in t else np.zeros((t["num_frames"], len(CONTACT_JOINTS)), bool)
                                    for t in tracks],
                                   [track_frames(t) for t in tracks], vo)
    observations.append(feet)
    points = np.asarray(cameras.get("points", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    observations.append(gait_observation(model, tracks, vo, up, fps))
    plane = map_ground_plane(points, vo, up) if tracks else None
    if plane is None:
        observations.append(ScaleObservation("ground", reason="no ground plane among the odometry's "
                                             f"{len(points)} map points"))
    else:
        contacts = []
        for track, track_contacts in zip(tracks, contact_vertices(model, tracks, contact_threshold)):
            per_frame = [np.zeros((0, 3))] * len(vo)
            per_frame[track["first_frame"]:track["first_frame"] + len(track_contacts)] = track_contacts
            contacts.append(per_frame)
        ground = scale_from_camera_height(contacts, vo, plane[:2], floor_points=points[plane[2]])
        ground.detail["map_points"] = int(plane[2].sum())
        observations.append(ground)
    if depth is not None and depth.get("available") and depth.get("metric"):
        observations.append(scale_from_depth(points, vo, depth["depth"], intrinsics))
    estimate = fuse(observations)
    if plane is not None:
        estimate.ground_plane = [*(float(v) for v in plane[0]), float(plane[1])]
    if log is not None:
        for o in observations:
            if o.usable():
                log.info("camera scale from %s: %.4g m per VO unit (+-%.1f%%, %d frames)", o.source, o.value,
                         100 * o.sigma, o.frames)
            else:
                log.info("camera scale from %s: not measured (%s)", o.source, o.reason)
        if ground.detail.get("camera_height_suspect") if plane is not None else False:
            log.warning("the ground source puts the moving camera %.2f m above the ground, outside the "
                        "plausible %.1f-%.1f m: its uncertainty is widened to +-%.0f%%",
                        ground.detail["camera_height_m"], *PLAUSIBLE_CAMERA_HEIGHT_M, 100 * ground.sigma)
        if not estimate.consistent:
            log.warning("%s", estimate.disagreement())
    return estimate


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
