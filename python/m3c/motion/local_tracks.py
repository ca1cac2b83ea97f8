"""Local human tracks (thesis 4.1.4, "Local Human Tracks Creation"): perception's tracks (m3c.perception.handover),
which hold a person's frames only, made to span every frame from the first to the last.

Frames in between without the person are filled: keypoints, translation, contacts and boxes linearly; root
orientation and every body joint rotation by spherical linear interpolation on SO(3) (as SLAHMR). Betas are
averaged over the seen frames (the optimizer keeps one shape per person).

Camera: a body estimated on a patch may come with the patch's weak-perspective camera (s, tx, ty) instead of a
translation: a body point X projects to patch coordinates s * (X_xy + (tx, ty)) in [-1, 1]. crop_to_full_camera
turns it into a translation in the full image's perspective camera (CLIFF's conversion, in m3c.perception.boxes),
so every person sits in one camera frame at its own place, and the tracks keep their positions relative to each
other (thesis Fig. 4.9) instead of all being centred in front of the camera.
"""

from __future__ import annotations

import numpy as np

from m3c.motion.interpolate import interpolate_linear, interpolate_rotations
from m3c.perception.boxes import crop_to_full_camera
from m3c.perception.types import NUM_COCO

REQUIRED = ("track_id", "frame", "square", "keypoints", "pose", "betas")


def camera_translations(track: dict, intrinsics) -> np.ndarray:
    """A perception track's translations (n, 3) in the full-image camera: its transl, or its crop_cam converted."""
    if "transl" in track:
        return np.asarray(track["transl"], dtype=np.float64)
    if "crop_cam" in track:
        return crop_to_full_camera(track["crop_cam"], track["square"], intrinsics)
    raise ValueError(f"track {track['track_id']}: give its camera as transl or crop_cam (it has {sorted(track)})")


def check_track(track: dict) -> int:
    """Checks a perception track's fields (REQUIRED, every per-frame array as long as frame, frames increasing);
    returns its number of frames."""
    missing = [k for k in REQUIRED if k not in track]
    if missing:
        raise ValueError(f"a perception track misses {', '.join(missing)} (has {sorted(track)})")
    frames = np.asarray(track["frame"])
    n = len(frames)
    for key in ("square", "keypoints", "pose", "betas", "transl", "crop_cam", "contacts", "ground_contacts"):
        if key in track and len(track[key]) != n:
            raise ValueError(f"track {track['track_id']}: {key} has {len(track[key])} rows, frame {n}")
    if n and (np.diff(frames) <= 0).any():
        raise ValueError(f"track {track['track_id']}: its frames must increase (one entry per frame), got "
                         f"{frames.tolist()}")
    return n


def fill_gaps(track: dict, intrinsics, gap_confidence: float = 0.0) -> dict:
    """One perception track -> its local track over every frame from its first to its last.

    Returns track_id, first_frame, num_frames m, visible (m,) bool, detection (m,) int (its row in the detections
    table, -1 in gaps; -1 throughout when the track has none), keypoints (m, 17, 3) float32 COCO-17 (interpolated
    in gaps, their confidence times gap_confidence), box (m, 4) float32 square boxes, transl (m, 3) and
    root_orient (m, 3) in the camera frame, body_pose (m, 23, 3), betas (B,), and contacts / ground_contacts
    (m, 4) where the track has them."""
    check_track(track)
    frames = np.asarray(track["frame"], dtype=np.int64)
    first, last = int(frames[0]), int(frames[-1])
    span = np.arange(first, last + 1)
    visible = np.isin(span, frames)
    detection = np.full(len(span), -1, dtype=np.int64)
    if "detection" in track:
        detection[frames - first] = track["detection"]
    t = frames.astype(np.float64)
    seen = np.asarray(track["keypoints"])[:, :NUM_COCO]  # the optimizer scores COCO-17
    keypoints = interpolate_linear(t, seen, span)
    keypoints[~visible, :, 2] *= gap_confidence
    keypoints[visible] = seen  # exact where seen
    pose = np.asarray(track["pose"], dtype=np.float64)
    rot = interpolate_rotations(t, pose, span)
    rot[visible] = pose
    out = {
        "track_id": int(track["track_id"]), "first_frame": first, "num_frames": len(span), "visible": visible,
        "detection": detection,
        "keypoints": keypoints.astype(np.float32),
        "box": interpolate_linear(t, track["square"], span).astype(np.float32),
        "transl": interpolate_linear(t, camera_translations(track, intrinsics), span),
        "root_orient": rot[:, 0],
        "body_pose": rot[:, 1:],
        "betas": np.asarray(track["betas"], dtype=np.float64).mean(axis=0),
    }
    for key in ("contacts", "ground_contacts"):
        if key in track:
            out[key] = np.clip(interpolate_linear(t, track[key], span), 0, 1)
    return out


def local_tracks(tracks: list[dict], intrinsics, min_visible_frames: int = 5,
                 gap_confidence: float = 0.0) -> tuple[list[dict], dict[int, int]]:
    """Perception's tracks -> (local tracks (fill_gaps) of those seen in at least min_visible_frames frames,
    {track id: frames seen} of the others, dropped as spurious detections)."""
    ids = [int(t["track_id"]) for t in tracks]
    if len(set(ids)) != len(ids):
        raise ValueError(f"track ids must be unique, got {sorted(ids)}")
    kept, dropped = [], {}
    for track in sorted(tracks, key=lambda t: int(t["track_id"])):
        n = check_track(track)
        if n < min_visible_frames:
            dropped[int(track["track_id"])] = n
        else:
            kept.append(fill_gaps(track, intrinsics, gap_confidence))
    return kept, dropped
