"""Boxes in frame pixels, and the thesis's patch preparation (4.1.2, "Box Processing" and "Subject Isolation"):
the one owner of the pixel convention, of box processing, of the pixels a box covers, of a mask read over pixels,
of the whitening rule and of patch sampling. The perception estimators and the pipeline nodes (m3c.nodes.boxes,
m3c.nodes.patches, m3c.nodes.records) call these.

Pixel convention (M3C's everywhere, OpenCV's: the README's results.npz, m3c::Intrinsics, m3c.viz.raster): pixel
(column i, row j) has its centre at (i, j) and covers [i - 0.5, i + 0.5) x [j - 0.5, j + 0.5); a W x H frame spans
[-0.5, W - 0.5] x [-0.5, H - 0.5] (frame_box). A box (x0, y0, x1, y1) is float in these coordinates; a tight box
runs over its pixels' outer edges. An integer box (patch_box, Person.mask_box, a tile) is a pixel index range
[x0, x1) x [y0, y1), as in frame[y0:y1, x0:x1]; pixel_region gives the one a box covers. Sources whose positions
count from the image's left edge convert where they enter: MediaPipe's landmarks (fractions of the image size,
mediapipe_pose.MediaPipeEngine.run), a mask's extent (mediapipe_pose.tight_box), OpenCV's HOG rectangles (hog.py).

Box processing (process_boxes): pad the tight box by `padding` pixels on every side (5 px in the thesis, so a
detection error does not cut off a limb), make it square around its centre (side = the longer side), shift the
square inside the frame where it overflows (when it fits; a square larger than the frame is centred on it), and
crop it to the frame. A patch samples the square itself, the part outside the frame white, so it is never
stretched (the thesis crops, then resizes the non-square crop, its Fig. 4.4).

Subject isolation (isolation_mask): inside a patch the other people's pixels are whitened (their tight boxes, or
only their masks inside their boxes where given), except the focused person's own mask (its tight box when it has
no mask): white rather than black, which the thesis found the models handle better.
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


def frame_box(frame_size: tuple[int, int]) -> np.ndarray:
    """The frame's extent (-0.5, -0.5, W - 0.5, H - 0.5) (the module's pixel convention). frame_size: (height,
    width)."""
    height, width = frame_size
    if height <= 0 or width <= 0:
        raise ValueError(f"frame_size must be positive (height, width), got {frame_size}")
    return np.array([-0.5, -0.5, width - 0.5, height - 0.5])


def clip_boxes(boxes, frame_size: tuple[int, int]) -> np.ndarray:
    """Boxes (..., 4) cut to the frame (frame_box)."""
    frame = frame_box(frame_size)
    return np.clip(np.asarray(boxes, dtype=np.float64), frame[[0, 1, 0, 1]], frame[[2, 3, 2, 3]])


def process_boxes(boxes, frame_size: tuple[int, int], padding: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Tight boxes (N, 4) -> (square (N, 4), crop (N, 4)) float: the padded square shifted into the frame (it may
    extend past the frame only when it is larger), and that square cut to the frame. frame_size: (height, width)."""
    frame = frame_box(frame_size)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if not np.isfinite(boxes).all() or (boxes[:, 2] < boxes[:, 0]).any() or (boxes[:, 3] < boxes[:, 1]).any():
        raise ValueError("boxes must be finite x0 y0 x1 y1 with x1 >= x0 and y1 >= y0")
    if not (np.isfinite(padding) and padding >= 0):
        raise ValueError(f"padding must be a finite number of pixels >= 0, got {padding}")
    padded = boxes + np.array([-padding, -padding, padding, padding])
    centre = (padded[:, :2] + padded[:, 2:]) / 2
    side = np.maximum(padded[:, 2] - padded[:, 0], padded[:, 3] - padded[:, 1])[:, None]
    first, size = frame[:2], frame[2:] - frame[:2]
    # Shift into the frame where the square fits; centre it on the frame where it does not.
    lo = np.where(side <= size, np.clip(centre - side / 2, first, first + np.maximum(size - side, 0.0)),
                  first + (size - side) / 2)
    square = np.concatenate([lo, lo + side], axis=1)
    return square, clip_boxes(square, frame_size)


def pixel_region(box, frame_size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The pixels a box covers, even in part, inside the frame: the index range [x0, x1) x [y0, y1) (x1 = x0 or
    y1 = y0 when none). Pixel i covers [i - 0.5, i + 0.5), so the range is floor(x0 + 0.5) .. ceil(x1 + 0.5)."""
    height, width = frame_size
    b = as_box(box) + 0.5
    x0, x1 = (int(np.clip(v, 0, width)) for v in (np.floor(b[0]), np.ceil(b[2])))
    y0, y1 = (int(np.clip(v, 0, height)) for v in (np.floor(b[1]), np.ceil(b[3])))
    return x0, y0, max(x1, x0), max(y1, y0)


def mask_in_region(mask: np.ndarray, origin, region) -> np.ndarray:
    """A mask (h, w) bool whose pixel (0, 0) is frame pixel origin = (x, y), over the frame index range region
    (x0, y0, x1, y1): (y1 - y0, x1 - x0) bool, False outside the mask."""
    mask = np.asarray(mask, dtype=bool)
    mx, my = (int(v) for v in origin)
    x0, y0, x1, y1 = (int(v) for v in region)
    out = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    ax0, ay0 = max(x0, mx), max(y0, my)
    ax1, ay1 = min(x1, mx + mask.shape[1]), min(y1, my + mask.shape[0])
    if ax1 > ax0 and ay1 > ay0:
        out[ay0 - y0:ay1 - y0, ax0 - x0:ax1 - x0] = mask[ay0 - my:ay1 - my, ax0 - mx:ax1 - mx]
    return out


def process_box(box, frame_size: tuple[int, int], padding: float = 5.0) -> np.ndarray:
    """The patch of one tight box: the pixels of its processed square's crop (process_boxes, pixel_region), as an
    integer-valued index range (x0, y0, x1, y1) inside [0, W] x [0, H]. frame_size: (height, width)."""
    _, cropped = process_boxes(as_box(box), frame_size, padding)
    return np.array(pixel_region(cropped[0], frame_size), dtype=np.float64)


def crop(frame: np.ndarray, box) -> np.ndarray:
    """A copy of the frame's pixels in an index range (as returned by process_box)."""
    x0, y0, x1, y1 = (int(v) for v in as_box(box))
    return np.ascontiguousarray(frame[y0:y1, x0:x1])


def isolation_mask(region, focus_box, other_boxes, focus_mask: np.ndarray | None = None,
                   other_masks: list | None = None) -> np.ndarray:
    """(h, w) bool: the pixels of a frame index range `region` (x0, y0, x1, y1), e.g. a patch or the whole frame, that
    subject isolation whitens for the focused person (see the module docstring).

    focus_box: the focused person's tight box; focus_mask: its (h, w) mask in region pixels, or None (then its
    tight box is kept). other_boxes: (N, 4) the other people's tight boxes; other_masks: per other person an
    (h, w) mask in region pixels or None (None, or a None entry: its whole box is whitened).
    """
    rx0, ry0, rx1, ry1 = (int(v) for v in as_box(region))
    h, w = ry1 - ry0, rx1 - rx0
    others = np.asarray(other_boxes, dtype=np.float64).reshape(-1, 4)
    if other_masks is not None and len(other_masks) != len(others):
        raise ValueError(f"other_masks must hold one entry per other box ({len(others)}), got {len(other_masks)}")

    def covered(box) -> np.ndarray:
        x0, y0, x1, y1 = pixel_region(np.asarray(box, dtype=np.float64) - [rx0, ry0, rx0, ry0], (h, w))
        out = np.zeros((h, w), dtype=bool)
        out[y0:y1, x0:x1] = True
        return out

    def in_region(mask, what) -> np.ndarray:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (h, w):
            raise ValueError(f"{what} must have the region's shape {(h, w)}, got {mask.shape}")
        return mask

    white = np.zeros((h, w), dtype=bool)
    for i, box in enumerate(others):
        mask = None if other_masks is None else other_masks[i]
        white |= covered(box) if mask is None else covered(box) & in_region(mask, f"other_masks[{i}]")
    keep = covered(focus_box) if focus_mask is None else in_region(focus_mask, "focus_mask")
    return white & ~keep


def isolate(patch: np.ndarray, patch_box, focus_box, other_boxes, focus_mask: np.ndarray | None = None,
            other_masks: list | None = None) -> np.ndarray:
    """A copy of the patch (h, w, 3), cut from the frame at the index range patch_box, with isolation_mask's pixels
    white. Boxes in frame pixels, masks in patch pixels (isolation_mask)."""
    out = np.array(patch, copy=True)
    out[isolation_mask(patch_box, focus_box, other_boxes, focus_mask, other_masks)] = WHITE
    return out


def extract_patch(frame: np.ndarray, square, size: int) -> np.ndarray:
    """The square (x0, y0, x1, y1; may extend past the frame) resampled bilinearly to size x size pixels, outside
    the frame white. The square's edges are the patch's edges: patch point p = size / side * (x - x0) - 0.5."""
    import cv2

    x0, y0, x1, _ = (float(v) for v in as_box(square))
    if not x1 > x0 or size < 1:
        raise ValueError(f"the square must have a positive side and size >= 1, got {square} and {size}")
    scale = size / (x1 - x0)
    M = np.array([[scale, 0.0, -scale * x0 - 0.5], [0.0, scale, -scale * y0 - 0.5]])
    return cv2.warpAffine(frame, M, (int(size), int(size)), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(WHITE, WHITE, WHITE))


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
    """A person's network input: image (h, w, 3) uint8 RGB, and where it lies in the frame (the module's pixel
    convention): input pixel (i, j)'s centre is at frame point origin + scale * (i, j). region: (x0, y0, x1, y1)
    the frame area the input covers (its pixels' outer edges), centred on the patch, with the input's aspect
    ratio."""

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
        patch = isolate(patch, patch_box, box, others, None if focus_mask_in is None else focus_mask_in(patch_box))
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
