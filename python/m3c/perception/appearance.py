"""Appearance descriptors for tracking: colour histograms inside a person's mask (PHALP's texture cue, offline).

The descriptor is a hue-saturation histogram of the coloured pixels plus a brightness histogram of the grey
ones, for the upper and the lower half of the person separately (shirts and trousers differ), normalised so the
whole descriptor sums to 1. Distances are Bhattacharyya distances in [0, 1].

pose_colour_descriptor is the same histogram pair taken where the keypoints put the torso and the thighs instead
of inside the mask: a patch holding two people has one mask over both, so only colours read at the keypoints
change when its keypoints move from one of them to the other.
"""

from __future__ import annotations

import numpy as np

from m3c.perception.boxes import as_box, mask_in_region, pixel_region

HUE_BINS, SAT_BINS, GREY_BINS = 16, 4, 8
DESCRIPTOR_SIZE = 2 * (HUE_BINS * SAT_BINS + GREY_BINS)


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 or float RGB in [0, 255] -> (..., 3) hue in [0, 1), saturation and value in [0, 1]."""
    x = np.asarray(rgb, dtype=np.float64) / 255.0
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    v = x.max(axis=-1)
    c = v - x.min(axis=-1)
    s = np.divide(c, v, out=np.zeros_like(v), where=v > 0)
    safe = np.where(c > 0, c, 1.0)
    h = np.where(v == r, ((g - b) / safe) % 6.0, np.where(v == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    h = np.where(c > 0, h / 6.0, 0.0) % 1.0
    return np.stack([h, s, v], axis=-1)


def _half_histogram(pixels: np.ndarray, min_saturation: float, min_value: float) -> np.ndarray:
    hsv = rgb_to_hsv(pixels)
    coloured = (hsv[:, 1] >= min_saturation) & (hsv[:, 2] >= min_value)
    h = np.minimum((hsv[coloured, 0] * HUE_BINS).astype(int), HUE_BINS - 1)
    s = np.minimum((hsv[coloured, 1] * SAT_BINS).astype(int), SAT_BINS - 1)
    colour = np.bincount(h * SAT_BINS + s, minlength=HUE_BINS * SAT_BINS).astype(np.float64)
    grey = np.bincount(np.minimum((hsv[~coloured, 2] * GREY_BINS).astype(int), GREY_BINS - 1),
                       minlength=GREY_BINS).astype(np.float64)
    hist = np.concatenate([colour, grey])
    total = hist.sum()
    return hist / total if total > 0 else hist


def appearance_descriptor(image: np.ndarray, box, mask: np.ndarray | None = None, mask_box=None,
                          min_saturation: float = 0.25, min_value: float = 0.15,
                          max_pixels: int = 4096) -> np.ndarray | None:
    """(DESCRIPTOR_SIZE,) descriptor of the person in `box` of an RGB image (H, W, 3), using only the pixels of
    `mask` ((h, w) bool inside the integer mask_box) when given, on a regular grid of about max_pixels
    samples (a histogram needs no more). None when no pixel is usable."""
    x0, y0, x1, y1 = pixel_region(box, image.shape[:2])
    if x1 <= x0 or y1 <= y0:
        return None
    region = image[y0:y1, x0:x1]
    if mask is None:
        keep = np.ones(region.shape[:2], dtype=bool)
    else:
        keep = mask_in_region(mask, as_box(mask_box)[:2], (x0, y0, x1, y1))
    step = max(1, int(np.sqrt(region.shape[0] * region.shape[1] / max_pixels)))
    region, keep = region[::step, ::step], keep[::step, ::step]
    if keep.sum() < 8:
        return None
    middle = region.shape[0] // 2
    halves = []
    for part, part_keep in ((region[:middle], keep[:middle]), (region[middle:], keep[middle:])):
        halves.append(_half_histogram(part[part_keep].reshape(-1, 3), min_saturation, min_value))
    descriptor = np.concatenate(halves)
    total = descriptor.sum()
    return descriptor / total if total > 0 else None


TORSO = (5, 6, 12, 11)   # COCO-17 shoulders and hips, around the torso
THIGHS = (11, 12, 14, 13)  # hips and knees


def _inside_polygon(u: np.ndarray, v: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Even-odd test of points (u, v) against a simple polygon's corners (n, 2) in order."""
    inside = np.zeros(u.shape, dtype=bool)
    for (u0, v0), (u1, v1) in zip(corners, np.roll(corners, -1, axis=0)):
        crosses = (v0 > v) != (v1 > v)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = u0 + (v - v0) * (u1 - u0) / (v1 - v0)
        inside ^= crosses & (u < at)
    return inside


def _quad_pixels(image: np.ndarray, corners: np.ndarray, shrink: float, max_pixels: int) -> np.ndarray:
    """RGB pixels (m, 3) inside four corners shrunk towards their centre by `shrink`, on a grid of about
    max_pixels samples; the corners ordered by angle, so a side view's crossed quadrilateral is still one."""
    centre = corners.mean(axis=0)
    corners = centre + shrink * (corners - centre)
    corners = corners[np.argsort(np.arctan2(corners[:, 1] - centre[1], corners[:, 0] - centre[0]))]
    h, w = image.shape[:2]
    x0, y0 = (int(max(0, np.floor(c))) for c in corners.min(axis=0))
    x1, y1 = (int(min(n, np.ceil(c) + 1)) for c, n in zip(corners.max(axis=0), (w, h)))
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 3), dtype=image.dtype)
    step = max(1, int(np.sqrt((x1 - x0) * (y1 - y0) / max_pixels)))
    v, u = np.mgrid[y0:y1:step, x0:x1:step]
    keep = _inside_polygon(u + 0.5, v + 0.5, corners)
    return image[v[keep], u[keep]]


def pose_colour_descriptor(image: np.ndarray, keypoints: np.ndarray, min_confidence: float = 0.5,
                           shrink: float = 0.8, min_saturation: float = 0.25, min_value: float = 0.15,
                           max_pixels: int = 2048) -> np.ndarray | None:
    """(DESCRIPTOR_SIZE,) colours where the keypoints (K >= 17, 3) put the person: the torso's quadrilateral
    (shoulders, hips) and the thighs' (hips, knees), each shrunk towards its centre by `shrink` to stay inside the
    body, as the upper and lower halves of appearance_descriptor. None when the shoulders and hips are not all
    seen with min_confidence; the thighs' half is empty when the knees are not."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    halves = []
    for quad in (TORSO, THIGHS):
        pixels = np.zeros((0, 3), dtype=np.uint8)
        if (keypoints[list(quad), 2] >= min_confidence).all():
            pixels = _quad_pixels(image, keypoints[list(quad), :2], shrink, max_pixels)
        if quad == TORSO and len(pixels) < 8:
            return None
        halves.append(_half_histogram(pixels, min_saturation, min_value) if len(pixels) >= 8
                      else np.zeros(HUE_BINS * SAT_BINS + GREY_BINS))
    descriptor = np.concatenate(halves)
    return descriptor / descriptor.sum()


def bhattacharyya_distance(p: np.ndarray, q: np.ndarray) -> float:
    """sqrt(1 - sum_i sqrt(p_i q_i)) for two histograms that each sum to 1; 0 = identical, 1 = disjoint."""
    bc = float(np.sum(np.sqrt(np.clip(p, 0, None) * np.clip(q, 0, None))))
    return float(np.sqrt(max(0.0, 1.0 - bc)))
