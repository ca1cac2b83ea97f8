"""Patch-level preparation (thesis 4.1.2): box processing and subject isolation.

Box processing turns a tight person box into the square patch region the patch-level models read:
  1. pad by `padding` pixels on every side (5 px in the thesis), so detection errors do not cut off limbs;
  2. squarify around the box centre (side = the longer side);
  3. shift the square inside the frame where it overflows (when it fits; a person larger than the frame keeps
     the overflow on both sides, centred);
  4. crop: the square clipped to the frame.
Patches sample the square region itself, the part outside the frame filled with white, so a patch is never
stretched: the thesis crops, then resizes the non-square crop, which distorts the aspect ratio (its Fig. 4.4).

Subject isolation whitens, inside a patch, the pixels of the other people in the frame (their tight boxes, or
their masks), except the pixels of the focused person's own mask (or tight box when there are no masks):
white rather than black, which the thesis found the models handle better.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import encode_images, mask_in_region, table_length
from m3c.pipeline import Node, register_node

WHITE = 255


def process_boxes(boxes: np.ndarray, width: int, height: int, padding: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Tight boxes (N, 4) x0 y0 x1 y1 -> (square (N, 4), crop (N, 4)), see the module docstring."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if (boxes[:, 2] < boxes[:, 0]).any() or (boxes[:, 3] < boxes[:, 1]).any():
        raise ValueError("boxes must be x0 y0 x1 y1 with x1 >= x0 and y1 >= y0")
    padded = boxes + np.array([-padding, -padding, padding, padding])
    centre = (padded[:, :2] + padded[:, 2:]) / 2
    side = np.maximum(padded[:, 2] - padded[:, 0], padded[:, 3] - padded[:, 1])
    lo = centre - side[:, None] / 2
    # The frame spans [-0.5, W - 0.5] x [-0.5, H - 0.5] (pixel centres at integers).
    first = -0.5
    size = np.array([width, height], dtype=np.float64)
    fits = side[:, None] <= size
    # Shift into the frame where the square fits; centre it on the frame where it does not.
    shifted = np.where(fits, np.clip(lo, first, first + np.maximum(size - side[:, None], 0.0)),
                       first + (size - side[:, None]) / 2)
    square = np.concatenate([shifted, shifted + side[:, None]], axis=1)
    crop = np.concatenate([np.maximum(square[:, :2], first), np.minimum(square[:, 2:], first + size)], axis=1)
    return square, crop


def box_region(box, width: int, height: int) -> tuple[int, int, int, int]:
    """The pixels whose centres lie inside a box, as the index range [x0, x1) x [y0, y1), clipped to the image."""
    x0, y0 = max(int(np.ceil(box[0])), 0), max(int(np.ceil(box[1])), 0)
    x1, y1 = min(int(np.floor(box[2])) + 1, width), min(int(np.floor(box[3])) + 1, height)
    return x0, y0, max(x1, x0), max(y1, y0)


def isolation_mask(height: int, width: int, focus: int, tight_boxes: np.ndarray, masks: dict | None,
                   rows: np.ndarray, whiten: str = "boxes") -> np.ndarray:
    """Image-sized bool mask of the pixels to whiten for detection `focus`, given the detections `rows` of the
    same frame (indices into tight_boxes / masks)."""
    out = np.zeros((height, width), dtype=bool)
    for other in rows:
        if other == focus:
            continue
        region = box_region(tight_boxes[other], width, height)
        x0, y0, x1, y1 = region
        if whiten == "masks" and masks is not None:
            out[y0:y1, x0:x1] |= mask_in_region(masks, int(other), region)
        else:
            out[y0:y1, x0:x1] = True
    # Keep the focused person: its mask, or without masks its tight box.
    region = box_region(tight_boxes[focus], width, height)
    x0, y0, x1, y1 = region
    if masks is not None:
        out[y0:y1, x0:x1] &= ~mask_in_region(masks, int(focus), region)
    else:
        out[y0:y1, x0:x1] = False
    return out


def extract_patch(frame: np.ndarray, square: np.ndarray, size: int) -> np.ndarray:
    """The square region (x0, y0, x1, y1; may extend past the frame) resampled to size x size; outside the frame
    is white. The square's edges map to the patch's edges: patch coordinate = size / side * (x - x0) - 0.5."""
    import cv2

    x0, y0, x1, _ = (float(v) for v in square)
    scale = size / (x1 - x0)
    M = np.array([[scale, 0.0, -scale * x0 - 0.5], [0.0, scale, -scale * y0 - 0.5]])
    return cv2.warpAffine(frame, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(WHITE, WHITE, WHITE))


@register_node
class PatchesNode(Node):
    """Isolated square patches, one per detection, streamed frame by frame from the video.
    Output patches: jpeg buffer + offsets (m3c.nodes.records.decode_image), size, whiten."""

    type_name = "patches"
    level = "patch"
    inputs = ("video", "detections", "boxes", "masks")
    optional_inputs = ("masks",)
    outputs = ("patches",)

    @dataclass
    class Config:
        size: int = 256  # pixels
        whiten: Literal["boxes", "masks"] = "boxes"  # what of the other people is whitened
        jpeg_quality: int = 95

    def run(self, ctx, inputs):
        video, detections, boxes, masks = inputs["video"], inputs["detections"], inputs["boxes"], inputs["masks"]
        n = table_length(detections, ("frame", "box"), "detections")
        frames = detections["frame"]
        patches: list[np.ndarray | None] = [None] * n
        rows_of = {f: np.flatnonzero(frames == f) for f in np.unique(frames)}
        with ctx.progress("isolating patches", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                rows = rows_of.get(i, ())
                for focus in rows:
                    white = isolation_mask(video["height"], video["width"], int(focus), detections["box"], masks,
                                           rows, self.config.whiten)
                    isolated = frame.copy()
                    isolated[white] = WHITE
                    patches[focus] = extract_patch(isolated, boxes["square"][focus], self.config.size)
                bar.update()
        missing = [k for k, p in enumerate(patches) if p is None]
        if missing:
            raise ValueError(f"detections refer to frames the video does not have (e.g. detection {missing[0]})")
        store = encode_images(patches, self.config.jpeg_quality)
        return {"patches": dict(store, size=self.config.size, whiten=self.config.whiten)}

    def visualize(self, ctx, inputs, outputs, folder):
        import cv2

        from m3c.nodes.records import decode_image

        store = outputs["patches"]
        count = len(store["offsets"]) - 1
        if count == 0:
            return []
        picks = np.linspace(0, count - 1, min(count, 16)).astype(int)
        tiles = [decode_image(store, int(k)) for k in picks]
        tiles += [np.full_like(tiles[0], WHITE)] * (-len(tiles) % 4)
        grid = np.vstack([np.hstack(tiles[r:r + 4]) for r in range(0, len(tiles), 4)])
        path = folder / "patches.jpg"
        cv2.imwrite(str(path), grid)
        return [path]
