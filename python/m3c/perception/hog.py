"""OpenCV's HOG + linear SVM people detector (Dalal-Triggs), weight-free beyond what OpenCV ships: a classical
alternative detector for the registry. Boxes only; masks and keypoints come from the segmenter and the 2D pose
estimator on the boxes' patches."""

from __future__ import annotations

import numpy as np

from m3c.perception._cv import import_cv2
from m3c.perception.boxes import clip_boxes, iou
from m3c.perception.interfaces import Detector
from m3c.perception.registry import register
from m3c.perception.types import FrameContext, Person

NAME = "hog"


@register("detector", NAME)
class HogDetector(Detector):
    """detect(): people boxes from cv2.HOGDescriptor's default people detector on a frame resized so its height
    is `work_height` pixels; overlapping boxes are merged by non-maximum suppression. Scores are the SVM margins
    mapped to (0, 1) by a logistic."""

    def __init__(self, work_height: int = 480, hit_threshold: float = 0.0, scale: float = 1.05,
                 nms_iou: float = 0.4, min_score: float = 0.5):
        cv2 = import_cv2()
        if work_height < 128:
            raise ValueError(f"work_height must be >= 128 (the detector's window is 64 x 128), got {work_height}")
        self.work_height, self.hit_threshold, self.scale = work_height, hit_threshold, scale
        self.nms_iou, self.min_score = nms_iou, min_score
        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def detect(self, ctx: FrameContext, known: list[Person] | None = None) -> list[Person]:
        cv2 = import_cv2()
        height, width = ctx.size
        factor = min(1.0, self.work_height / height)
        image = ctx.image if factor == 1.0 else cv2.resize(ctx.image, (int(round(width * factor)), self.work_height),
                                                           interpolation=cv2.INTER_AREA)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        rects, weights = self._hog.detectMultiScale(gray, hitThreshold=self.hit_threshold, winStride=(8, 8),
                                                    padding=(8, 8), scale=self.scale)
        if len(rects) == 0:
            return []
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        scores = 1.0 / (1.0 + np.exp(-np.asarray(weights, dtype=np.float64).reshape(-1)))
        keep = cv2.dnn.NMSBoxes(rects.tolist(), scores.tolist(), self.min_score, self.nms_iou)
        people = []
        for i in np.asarray(keep, dtype=int).reshape(-1):
            # The rectangle's pixels [x, x + w) of the resized image: edges x - 0.5 and x + w - 0.5 there, and
            # (edge + 0.5) / factor - 0.5 in the frame (m3c.perception.boxes's pixel convention).
            x, y, w, h = rects[i]
            box = clip_boxes(np.array([x, y, x + w, y + h]) / factor - 0.5, ctx.size)
            if any(iou(box, k.box) > 0.5 for k in known or []):
                continue
            people.append(Person(box, float(scores[i]), sources={"detector": NAME}))
        return people
