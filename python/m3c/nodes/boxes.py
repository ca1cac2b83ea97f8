"""The boxes node: square patch boxes per detection (m3c.perception.boxes.process_boxes)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import table_length
from m3c.perception.boxes import process_boxes
from m3c.pipeline import Node, register_node


@register_node
class BoxesNode(Node):
    """Square patch boxes per detection (process_boxes). Output boxes: square (N, 4), crop (N, 4) float32."""

    type_name = "boxes"
    level = "patch"
    inputs = ("video", "detections")
    outputs = ("boxes",)

    @dataclass
    class Config:
        padding: float = 5.0  # pixels

        def __post_init__(self):
            if not (math.isfinite(self.padding) and self.padding >= 0):
                raise ValueError(f"padding must be a finite number of pixels >= 0, got {self.padding}")

    def run(self, ctx, inputs):
        video, detections = inputs["video"], inputs["detections"]
        table_length(detections, ("frame", "box"), "detections")
        square, crop = process_boxes(detections["box"], (video["height"], video["width"]), self.config.padding)
        return {"boxes": {"square": square.astype(np.float32), "crop": crop.astype(np.float32)}}

    def visualize(self, ctx, inputs, outputs, folder):
        import cv2

        detections, boxes = inputs["detections"], outputs["boxes"]
        if len(detections["frame"]) == 0:
            return []
        # The frame with the most people.
        counts = np.bincount(detections["frame"])
        target = int(np.argmax(counts))
        for i, frame in stream_frames(ctx, inputs["video"]):
            if i == target:
                break
        rows = np.flatnonzero(detections["frame"] == target)
        for n in rows:
            for box, colour in ((detections["box"][n], (0, 200, 0)), (boxes["square"][n], (0, 0, 255))):
                cv2.rectangle(frame, tuple(int(round(v)) for v in box[:2]), tuple(int(round(v)) for v in box[2:]),
                              colour, 2)
        path = folder / f"boxes_frame{target:05d}.jpg"
        cv2.imwrite(str(path), frame)
        return [path]
