"""The data passed between nodes, and compact encodings for the bulky parts (masks, image patches).

Frame-level and patch-level outputs are tables over detections: arrays of equal length N, row n being detection
n, aligned with `detections["frame"]`. Frame indices count processed frames (0 .. T-1; the frames node maps them
to video frame ids). Pixel coordinates follow OpenCV (as intrinsics and keypoints do): pixel (i, j)'s centre is
at (i, j), so the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]. Boxes are (x0, y0, x1, y1) in these coordinates.

    detections  frame (N,) int64, box (N, 4) float32 tight person boxes, square (N, 4) float32 their padded
                square boxes shifted into the frame (m3c.perception.boxes.process_boxes; may extend past it when
                the person is larger than the frame), score (N,) float32
    masks       one binary mask per detection, stored inside its tight box (encode_masks / mask_in_region)
    patches     one isolated, square, size x size image per detection around detections["square"] (JPEG in a
                buffer)
    cameras     world_from_cam (T, 4, 4) from visual odometry (translation up to scale), static (bool)

Track-level outputs hold one dict per person instead: perception's tracks (m3c.perception.handover, the person's
own frames) and the local tracks (m3c.motion.local_tracks, every frame from the first to the last, gaps filled).
"""

from __future__ import annotations

import numpy as np

from m3c.perception.boxes import mask_in_region as place_mask
from m3c.perception.types import pack_mask
from m3c.pipeline import PipelineError


def table_length(table: dict, columns: tuple[str, ...], where: str) -> int:
    """Checks that `columns` of a per-detection table exist and share their first dimension; returns N."""
    lengths = {}
    for column in columns:
        if column not in table:
            raise PipelineError(f"{where}: missing column {column!r} (has {sorted(table)})")
        lengths[column] = len(np.asarray(table[column]))
    if len(set(lengths.values())) > 1:
        raise PipelineError(f"{where}: columns have different lengths {lengths}")
    return next(iter(lengths.values()), 0)


# Masks ------------------------------------------------------------------------------------------------------
def encode_masks(masks: list[tuple[np.ndarray, int, int]]) -> dict:
    """Masks as (bool array h x w, x0, y0) regions of the image -> one packed bit buffer.
    Returns {"bits": uint8, "offsets": (N + 1,) int64, "regions": (N, 4) int32 x0, y0, x1, y1}."""
    return encode_packed_masks([(*pack_mask(mask), x0, y0) for mask, x0, y0 in masks])


def encode_packed_masks(masks: list[tuple[np.ndarray, int, int, int, int]]) -> dict:
    """encode_masks of masks already packed by pack_mask: (bits, h, w, x0, y0) each."""
    chunks, offsets, regions = [], [0], []
    for bits, h, w, x0, y0 in masks:
        if len(bits) != (h * w + 7) // 8:
            raise PipelineError(f"a packed {h} x {w} mask needs {(h * w + 7) // 8} bytes, got {len(bits)}")
        chunks.append(bits)
        offsets.append(offsets[-1] + len(bits))
        regions.append((x0, y0, x0 + w, y0 + h))
    return {"bits": np.concatenate(chunks) if chunks else np.zeros(0, np.uint8),
            "offsets": np.asarray(offsets, dtype=np.int64),
            "regions": np.asarray(regions, dtype=np.int32).reshape(-1, 4)}


def decode_mask(masks: dict, n: int) -> tuple[np.ndarray, int, int]:
    """Detection n's mask: (bool h x w, x0, y0)."""
    x0, y0, x1, y1 = (int(v) for v in masks["regions"][n])
    bits = masks["bits"][masks["offsets"][n]:masks["offsets"][n + 1]]
    h, w = y1 - y0, x1 - x0
    return np.unpackbits(bits, count=h * w).astype(bool).reshape(h, w), x0, y0


def mask_in_region(masks: dict, n: int, region: tuple[int, int, int, int]) -> np.ndarray:
    """Detection n's mask over the image region (x0, y0, x1, y1) (bool, zero outside the stored mask)."""
    mask, mx, my = decode_mask(masks, n)
    return place_mask(mask, (mx, my), region)



def rows_by_frame(detections: dict) -> dict[int, list[int]]:
    """frame index -> the detection rows in that frame."""
    rows: dict[int, list[int]] = {}
    for n, frame in enumerate(np.asarray(detections["frame"])):
        rows.setdefault(int(frame), []).append(n)
    return rows


def people_mask(masks: dict, rows: list[int], width: int, height: int) -> np.ndarray:
    """bool (height, width): the union of the masks of detection rows `rows` (everyone seen in one frame)."""
    mask = np.zeros((height, width), dtype=bool)
    for n in rows:
        mask |= mask_in_region(masks, n, (0, 0, width, height))
    return mask

# Patches ----------------------------------------------------------------------------------------------------
def encode_images(images: list[np.ndarray], quality: int) -> dict:
    """BGR uint8 images -> {"jpeg": uint8 buffer, "offsets": (N + 1,) int64}."""
    import cv2

    chunks, offsets = [], [0]
    for image in images:
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        if not ok:
            raise PipelineError("JPEG encoding of a patch failed")
        chunks.append(data.reshape(-1))
        offsets.append(offsets[-1] + len(chunks[-1]))
    return {"jpeg": np.concatenate(chunks) if chunks else np.zeros(0, np.uint8),
            "offsets": np.asarray(offsets, dtype=np.int64)}


def decode_image(store: dict, n: int) -> np.ndarray:
    import cv2

    data = store["jpeg"][store["offsets"][n]:store["offsets"][n + 1]]
    image = cv2.imdecode(np.asarray(data), cv2.IMREAD_COLOR)
    if image is None:
        raise PipelineError(f"patch {n} does not decode")
    return image
