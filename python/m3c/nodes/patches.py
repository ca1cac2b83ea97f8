"""The patches node: the thesis's isolated square patches (4.1.2), one per detection, around the square boxes
perception handed over (detections["square"]). Box processing, the whitening rule and the sampling are
m3c.perception.boxes's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import decode_mask, encode_images, mask_in_region, table_length
from m3c.perception.boxes import WHITE, extract_patch, isolate
from m3c.pipeline import Node, register_node


def _frame_mask(masks: dict | None, n: int, video: dict) -> np.ndarray | None:
    """Detection n's mask over the whole frame, or None when there are no masks or its mask is empty."""
    if masks is None or decode_mask(masks, n)[0].size == 0:
        return None
    return mask_in_region(masks, n, (0, 0, video["width"], video["height"]))


@register_node
class PatchesNode(Node):
    """Isolated square patches, one per detection, streamed frame by frame from the video.
    Output patches: jpeg buffer + offsets (m3c.nodes.records.decode_image), size, whiten."""

    type_name = "patches"
    level = "patch"
    inputs = ("video", "detections", "masks")
    optional_inputs = ("masks",)
    outputs = ("patches",)
    # 2: the whitening rule of m3c.perception.boxes (a person without a mask keeps its tight box)
    # 3: the square boxes from the detections table (the boxes node is gone)
    version = "3"

    @dataclass
    class Config:
        size: int = 256  # pixels
        whiten: Literal["boxes", "masks"] = "boxes"  # what of the other people is whitened
        jpeg_quality: int = 95

    def run(self, ctx, inputs):
        video, detections, masks = inputs["video"], inputs["detections"], inputs["masks"]
        n = table_length(detections, ("frame", "box", "square"), "detections")
        frames = detections["frame"]
        patches: list[np.ndarray | None] = [None] * n
        rows_of = {f: np.flatnonzero(frames == f) for f in np.unique(frames)}
        with ctx.progress("isolating patches", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                rows = rows_of.get(i, ())
                for focus in rows:
                    others = [int(r) for r in rows if r != focus]
                    own = _frame_mask(masks, int(focus), video)
                    theirs = [_frame_mask(masks, r, video) for r in others] if self.config.whiten == "masks" else None
                    isolated = isolate(frame, (0, 0, video["width"], video["height"]), detections["box"][focus],
                                       detections["box"][others], own, theirs)
                    patches[focus] = extract_patch(isolated, detections["square"][focus], self.config.size)
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
