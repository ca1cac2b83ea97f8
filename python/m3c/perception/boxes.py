"""Patch-level box processing and subject isolation (thesis 4.1.2, "Box Processing" and "Subject Isolation").

Boxes are (x0, y0, x1, y1) in pixels, x1/y1 exclusive, float. A frame is (H, W, 3) uint8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WHITE = 255


def as_box(box) -> np.ndarray:
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,) or not np.isfinite(b).all() or b[2] < b[0] or b[3] < b[1]:
        raise ValueError(f"a box must be 4 finite numbers (x0, y0, x1, y1) with x1 >= x0 and y1 >= y0, got {box}")
    return b


def box_area(box) -> float:
    b = as_box(box)
    return float((b[2] - b[0]) * (b[3] - b[1]))


def iou(a, b) -> float:
    """Intersection over union of two boxes (0 when both are empty)."""
    a, b = as_box(a), as_box(b)
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(w, 0.0) * max(h, 0.0)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(A, B) IoU of every pair; boxes (A, 4) and (B, 4)."""
    a = np.asarray(boxes_a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=np.float64).reshape(-1, 4)
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.clip(w, 0, None) * np.clip(h, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def process_box(box, frame_size: tuple[int, int], padding: float = 5.0) -> np.ndarray:
    """The thesis's four steps: pad the tight box by `padding` pixels, make it square around its centre, shift it
    inside the frame, and crop what still spills over (a box larger than the frame then loses its squareness).

    frame_size: (height, width). Returns integer-valued (x0, y0, x1, y1) inside [0, W] x [0, H].
    """
    height, width = frame_size
    if height <= 0 or width <= 0:
        raise ValueError(f"frame_size must be positive (height, width), got {frame_size}")
    b = as_box(box)
    x0, y0, x1, y1 = b[0] - padding, b[1] - padding, b[2] + padding, b[3] + padding
    side = max(x1 - x0, y1 - y0)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    x0, x1 = cx - side / 2, cx + side / 2
    y0, y1 = cy - side / 2, cy + side / 2
    # Shift inside the frame; a box larger than the frame starts at its edge and is cropped below.
    dx = -x0 if x0 < 0 else (width - x1 if x1 > width else 0.0)
    dy = -y0 if y0 < 0 else (height - y1 if y1 > height else 0.0)
    x0, x1, y0, y1 = x0 + dx, x1 + dx, y0 + dy, y1 + dy
    out = np.array([np.floor(x0), np.floor(y0), np.ceil(x1), np.ceil(y1)])
    out[[0, 2]] = np.clip(out[[0, 2]], 0, width)
    out[[1, 3]] = np.clip(out[[1, 3]], 0, height)
    return out


def crop(frame: np.ndarray, box) -> np.ndarray:
    """A copy of the frame's pixels inside an integer box (as returned by process_box)."""
    x0, y0, x1, y1 = (int(v) for v in as_box(box))
    return np.ascontiguousarray(frame[y0:y1, x0:x1])


def isolate(patch: np.ndarray, patch_box, other_boxes, focus_mask: np.ndarray | None = None,
            other_masks: list | None = None) -> np.ndarray:
    """Whitens, inside a patch, the pixels of the other people (thesis: "whitening out pixels that belong to other
    nearby tight bounding boxes ... except those within the focused human's segmentation mask").

    patch: (h, w, 3) cut from the frame at patch_box (integer box). other_boxes: (N, 4) tight boxes of the other
    people, frame pixels. focus_mask: (h, w) bool mask of the focused person in patch pixels, or None.
    other_masks: per other person, an (h, w) bool mask in patch pixels or None; where given, only the mask
    (not the whole box) is whitened, so a neighbour's box that covers background keeps it.
    Returns a whitened copy.
    """
    out = np.array(patch, copy=True)
    h, w = out.shape[:2]
    px0, py0 = int(as_box(patch_box)[0]), int(as_box(patch_box)[1])
    keep = np.zeros((h, w), dtype=bool) if focus_mask is None else np.asarray(focus_mask, dtype=bool)
    if keep.shape != (h, w):
        raise ValueError(f"focus_mask must have the patch's shape {(h, w)}, got {keep.shape}")
    others = np.asarray(other_boxes, dtype=np.float64).reshape(-1, 4)
    for i, box in enumerate(others):
        x0 = int(np.clip(np.floor(box[0]) - px0, 0, w))
        x1 = int(np.clip(np.ceil(box[2]) - px0, 0, w))
        y0 = int(np.clip(np.floor(box[1]) - py0, 0, h))
        y1 = int(np.clip(np.ceil(box[3]) - py0, 0, h))
        if x1 <= x0 or y1 <= y0:
            continue
        region = np.zeros((h, w), dtype=bool)
        region[y0:y1, x0:x1] = True
        mask = None if other_masks is None else other_masks[i]
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != (h, w):
                raise ValueError(f"other_masks[{i}] must have the patch's shape {(h, w)}, got {mask.shape}")
            region &= mask
        out[region & ~keep] = WHITE
    return out


def crop_to_full_camera(crop_cam: np.ndarray, square: np.ndarray, intrinsics) -> np.ndarray:
    """Weak-perspective patch cameras (N, 3) = (s, tx, ty) of square boxes (N, 4) -> translations (N, 3) in
    the full-image camera (metres, OpenCV frame).

    The depth makes the body's scale match: tz = 2 f / (b s), with b the box side in pixels and f = (fx + fy) / 2.
    x and y then make the body origin project where the weak-perspective camera put it, the box centre plus
    b s (tx, ty) / 2 pixels: t_x = (c_x - p_x + b s tx / 2) tz / fx (p = principal point); for fx = fy this is
    CLIFF's t_x = tx + 2 (c_x - p_x) / (b s).
    """
    crop_cam = np.asarray(crop_cam, dtype=np.float64).reshape(-1, 3)
    square = np.asarray(square, dtype=np.float64).reshape(-1, 4)
    fx, fy, px, py = (float(v) for v in intrinsics)
    s, tx, ty = crop_cam.T
    side = square[:, 2] - square[:, 0]
    centre_x, centre_y = (square[:, 0] + square[:, 2]) / 2, (square[:, 1] + square[:, 3]) / 2
    bs = side * s
    if (bs <= 0).any() or not np.isfinite(bs).all():
        raise ValueError("crop camera scale s and box side must be positive and finite")
    tz = (fx + fy) / bs
    return np.stack([(centre_x - px + bs * tx / 2) * tz / fx, (centre_y - py + bs * ty / 2) * tz / fy, tz], axis=1)


def full_to_crop_camera(transl: np.ndarray, square: np.ndarray, intrinsics) -> np.ndarray:
    """The inverse of crop_to_full_camera (for tests and for backends that fit in the full image)."""
    transl = np.asarray(transl, dtype=np.float64).reshape(-1, 3)
    square = np.asarray(square, dtype=np.float64).reshape(-1, 4)
    fx, fy, px, py = (float(v) for v in intrinsics)
    side = square[:, 2] - square[:, 0]
    centre_x, centre_y = (square[:, 0] + square[:, 2]) / 2, (square[:, 1] + square[:, 3]) / 2
    bs = (fx + fy) / transl[:, 2]
    s = bs / side
    tx = (transl[:, 0] * fx / transl[:, 2] - centre_x + px) * 2 / bs
    ty = (transl[:, 1] * fy / transl[:, 2] - centre_y + py) * 2 / bs
    return np.stack([s, tx, ty], axis=1)


@dataclass(frozen=True)
class NetworkInput:
    """A person's network input: image (h, w, 3) uint8 RGB, and where it lies in the frame: input pixel (i, j)
    is frame pixel origin + scale * (i, j) (pixel centres at integers). region: (x0, y0, x1, y1) the frame area
    the input covers (pixel corners), centred on the patch, with the input's aspect ratio."""

    image: np.ndarray
    origin: np.ndarray
    scale: np.ndarray
    region: np.ndarray


def network_input(frame: np.ndarray, box, others=(), focus_mask_in=None, size: tuple[int, int] = (256, 256),
                  padding: float = 5.0) -> NetworkInput:
    """The thesis's patch of a person for a network reading `size` = (height, width) pixels.

    The tight `box` becomes the square patch of process_box (padding, squared, shifted inside the frame); the
    other people's tight boxes `others` (N, 4) are whitened in it except the focused person's mask
    (`focus_mask_in(patch_box)` -> (h, w) bool, e.g. Person.mask_in, or None); the patch is then widened to the
    network's aspect ratio around its centre (the added margin is white, nothing is stretched) and resampled
    bilinearly, the region's corners on the input's corners.
    """
    import cv2

    height, width = int(size[0]), int(size[1])
    if height < 2 or width < 2:
        raise ValueError(f"size must be at least 2 x 2 pixels, got {size}")
    patch_box = process_box(box, frame.shape[:2], padding)
    patch = crop(frame, patch_box)
    if patch.size == 0:
        raise ValueError(f"the box {as_box(box)} leaves no pixels of the {frame.shape[1]} x {frame.shape[0]} frame")
    others = np.asarray(others, dtype=np.float64).reshape(-1, 4)
    if len(others):
        patch = isolate(patch, patch_box, others, None if focus_mask_in is None else focus_mask_in(patch_box))
    ph, pw = patch.shape[:2]
    # One scale for x and y (nothing stretched): the region is the patch widened to the input's aspect ratio.
    scale = np.full(2, max(pw / width, ph / height))
    centre = np.array([patch_box[0] + (pw - 1) / 2.0, patch_box[1] + (ph - 1) / 2.0])
    origin = centre - 0.5 * scale * np.array([width - 1, height - 1])
    # Input pixel (i, j) samples patch pixel (origin - patch origin) + scale * (i, j).
    warp = np.array([[scale[0], 0.0, origin[0] - patch_box[0]], [0.0, scale[1], origin[1] - patch_box[1]]])
    image = cv2.warpAffine(np.ascontiguousarray(patch), warp, (width, height),
                           flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=(WHITE, WHITE, WHITE))
    region = np.concatenate([origin - 0.5 * scale, origin + scale * np.array([width - 1, height - 1]) + 0.5 * scale])
    return NetworkInput(image, origin, scale, region)
