"""Checks of perception results that need no ground truth (used by the real-clip tests and the benchmark)."""

from __future__ import annotations

import numpy as np

from m3c.perception.pipeline import MASK_DOWNSAMPLE, PerceptionResult, PersonTrack


def mask_boxes(result: PerceptionResult) -> list:
    """Per frame, the bounding box (x0, y0, x1, y1, pixels) of the frame's human mask, or None where it is
    empty (frame_masks are stored 4x downsampled, so boxes are good to about 4 px)."""
    if result.frame_masks is None:
        raise ValueError("the result has no frame masks (PerceptionConfig.save_masks was off)")
    width = result.image_size[1]
    boxes = []
    for packed in result.frame_masks:
        mask = np.unpackbits(packed, axis=1)[:, :(width + MASK_DOWNSAMPLE - 1) // MASK_DOWNSAMPLE].astype(bool)
        if not mask.any():
            boxes.append(None)
            continue
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        s = MASK_DOWNSAMPLE
        boxes.append(np.array([cols[0] * s, rows[0] * s, (cols[-1] + 1) * s, (rows[-1] + 1) * s], dtype=float))
    return boxes


def keypoints_in_mask_box(result: PerceptionResult, track: PersonTrack, min_confidence: float = 0.5,
                          margin: float = 0.05) -> np.ndarray:
    """Per frame of a track (in a single-person video), whether every COCO-17 keypoint with confidence >=
    min_confidence lies inside the box of the segmentation mask, enlarged by margin of its height on each side:
    the keypoints and the segmentation agree on where the person is."""
    boxes = mask_boxes(result)
    inside = np.zeros(len(track.frame_ids), dtype=bool)
    for i, f in enumerate(track.frame_ids):
        box = boxes[f]
        if box is None:
            continue
        grow = margin * (box[3] - box[1])
        k = track.keypoints[i, :17]
        k = k[k[:, 2] >= min_confidence]
        inside[i] = bool(np.all((k[:, 0] >= box[0] - grow) & (k[:, 0] <= box[2] + grow) &
                                (k[:, 1] >= box[1] - grow) & (k[:, 1] <= box[3] + grow)))
    return inside
