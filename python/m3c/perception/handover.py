"""What perception hands over to the rest of the pipeline: its tracks whole, and the people of every frame.

A person enters the hand-over in the frames where the body fit succeeded (bodies.valid); a track with no such
frame is left out. Each track keeps everything perception computed for it, in its own frames:

    track_id     int
    frame        (n,) int64 frame indices, increasing
    detection    (n,) int64 the rows of these frames in the detections table
    box          (n, 4) float32 tight boxes; square (n, 4) float32 their padded square boxes
                 (m3c.perception.boxes.process_boxes)
    score        (n,) float32 detection confidences
    keypoints    (n, K, 3) float32 u, v, confidence: COCO-17, then the foot points (types.FOOT_KEYPOINT_NAMES)
                 when the pose estimator gave them (K = 17 or 21)
    pose         (n, 24, 3) float64 axis-angle, root relative to the camera; betas (n, B) float64
    transl       (n, 3) float64 metres in the full-image camera (a track given by another tool may hold
                 crop_cam (n, 3) instead: the patch's weak-perspective camera, see crop_to_full_camera)
    contacts     (n, 4) float32 planted probabilities of m3c.body.joint_names.CONTACT_JOINTS
    ground_contacts (n, 4) float32, only when the contacts also read the images: on the ground by heights alone

The frame-level tables (detections: frame, box, square, score; one mask per row) hold the same people, one row
per person per frame, ordered by frame then descending score: the nodes that hide people from the odometry read
them frame by frame.
"""

from __future__ import annotations

import numpy as np

from m3c.perception.boxes import process_boxes


def hand_over(result, padding: float = 5.0) -> tuple[list[dict], dict, list]:
    """A PerceptionResult -> (tracks, detections, masks): the tracks as above, the detections table, and per
    detection row its mask as (packed bits, h, w, x0, y0) (an empty mask where perception kept none).
    padding: pixels added around each tight box before it is squared (the thesis's 5)."""
    height, width = (int(v) for v in result.image_size)
    tracks, masks = [], []
    for track in result.tracks:
        rows = np.flatnonzero(track.bodies.valid)
        if not len(rows):
            continue
        entry = {
            "track_id": int(track.track_id),
            "frame": np.asarray(track.frame_ids, dtype=np.int64)[rows],
            "box": np.asarray(track.boxes, dtype=np.float32)[rows],
            "score": np.asarray(track.scores, dtype=np.float32)[rows],
            "keypoints": np.asarray(track.keypoints, dtype=np.float32)[rows],
            "pose": np.asarray(track.bodies.pose, dtype=np.float64)[rows],
            "betas": np.asarray(track.bodies.betas, dtype=np.float64)[rows],
            "transl": np.asarray(track.bodies.transl, dtype=np.float64)[rows],
            "contacts": np.asarray(track.contacts, dtype=np.float32)[rows],
        }
        if track.ground_contacts is not None:
            entry["ground_contacts"] = np.asarray(track.ground_contacts, dtype=np.float32)[rows]
        for i in rows:
            mask = track.masks[i] if track.masks is not None else None
            if mask is None:
                masks.append((np.zeros(0, np.uint8), 0, 0, 0, 0))
            else:
                (bits, h, w), box = mask
                masks.append((bits, h, w, int(box[0]), int(box[1])))
        tracks.append((entry, np.asarray(track.scores, dtype=np.float64)[rows]))
    frame = np.concatenate([t["frame"] for t, _ in tracks]) if tracks else np.zeros(0, np.int64)
    score = np.concatenate([s for _, s in tracks]) if tracks else np.zeros(0)
    order = np.lexsort((-score, frame))
    row_of = np.empty(len(order), dtype=np.int64)
    row_of[order] = np.arange(len(order))
    box = np.concatenate([t["box"] for t, _ in tracks]) if tracks else np.zeros((0, 4), np.float32)
    square = process_boxes(box, (height, width), padding)[0].astype(np.float32)
    detections = {"frame": frame[order], "box": box[order], "square": square[order],
                  "score": np.concatenate([t["score"] for t, _ in tracks])[order] if tracks
                  else np.zeros(0, np.float32)}
    start = 0
    out = []
    for entry, _ in tracks:
        n = len(entry["frame"])
        entry["detection"] = row_of[start:start + n]
        entry["square"] = square[start:start + n]
        start += n
        out.append(entry)
    return out, detections, [masks[k] for k in order]
