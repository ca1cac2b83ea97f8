"""What the perception estimators exchange: one person in one frame, and the frame being processed."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from m3c.perception.boxes import as_box, mask_in_region

# Keypoint rows: COCO-17 (m3c.body.joint_names.COCO17_NAMES), optionally followed by these foot points (body
# model vertices of the same names), which fix the feet's orientation for the body fit and the contacts.
FOOT_KEYPOINT_NAMES = ("left_heel", "right_heel", "left_big_toe", "right_big_toe")
NUM_COCO = 17
NUM_WITH_FEET = NUM_COCO + len(FOOT_KEYPOINT_NAMES)


def pose_distance(a: np.ndarray, b: np.ndarray, confident_a: float = 0.0, confident_b: float = 0.0) -> float:
    """How far apart two people's keypoints (K >= 17, 3) lie: the mean image distance over the COCO-17 keypoints
    both see (confidence above confident_a, confident_b), in units of a's height (the extent of its keypoints seen
    there, at least 8 px); inf when fewer than 3 are seen by both."""
    a, b = np.asarray(a, dtype=np.float64)[:NUM_COCO], np.asarray(b, dtype=np.float64)[:NUM_COCO]
    both = (a[:, 2] > confident_a) & (b[:, 2] > confident_b)
    if both.sum() < 3:
        return float("inf")
    height = max(float(np.ptp(a[both, 1])), 8.0)
    return float(np.linalg.norm(a[both, :2] - b[both, :2], axis=-1).mean() / height)


def pack_mask(mask: np.ndarray) -> tuple[np.ndarray, int, int]:
    """A bool mask h x w -> (its bits packed row-major, h, w): an eighth of its memory. Tracks keep their people's
    masks packed so a long video's masks do not pile up (m3c.nodes.records stores them in the same packing)."""
    mask = np.asarray(mask, dtype=bool)
    return np.packbits(mask.reshape(-1)), int(mask.shape[0]), int(mask.shape[1])


@dataclass
class Person:
    """One person in one frame, frame pixels (OpenCV image axes: u right, v down).

    box: (4,) tight box x0, y0, x1, y1. score: detection confidence in [0, 1].
    keypoints: (K, 3) u, v, confidence (0 = not seen), K = 17 (COCO-17) or 21 (COCO-17 then
        FOOT_KEYPOINT_NAMES), or None before 2D pose estimation.
    keypoints3d: (K, 4) root-relative metric 3D keypoints x, y, z (metres, camera axes, origin at the hip
        centre) and confidence, same rows as keypoints, or None when the pose estimator gives none.
    mask: (h, w) bool segmentation inside mask_box (integer box, (h, w) = its size), or None.
    sources: which estimator produced each part, task -> estimator name ("detector": "mediapipe", ...).
    """

    box: np.ndarray
    score: float
    keypoints: np.ndarray | None = None
    keypoints3d: np.ndarray | None = None
    mask: np.ndarray | None = None
    mask_box: np.ndarray | None = None
    sources: dict = field(default_factory=dict)

    def __post_init__(self):
        self.box = as_box(self.box)
        if self.keypoints is not None:
            self.keypoints = np.asarray(self.keypoints, dtype=np.float64)
            if self.keypoints.shape not in ((NUM_COCO, 3), (NUM_WITH_FEET, 3)):
                raise ValueError(f"keypoints must have shape (17, 3) or (21, 3), got {self.keypoints.shape}")
        if self.keypoints3d is not None:
            self.keypoints3d = np.asarray(self.keypoints3d, dtype=np.float64)
            rows = NUM_COCO if self.keypoints is None else len(self.keypoints)
            if self.keypoints3d.shape != (rows, 4):
                raise ValueError(f"keypoints3d must have shape ({rows}, 4) like keypoints, got "
                                 f"{self.keypoints3d.shape}")
        if (self.mask is None) != (self.mask_box is None):
            raise ValueError("mask and mask_box go together: give both or neither")
        if self.mask is not None:
            self.mask_box = as_box(self.mask_box).astype(np.int64)
            self.mask = np.asarray(self.mask, dtype=bool)
            size = (int(self.mask_box[3] - self.mask_box[1]), int(self.mask_box[2] - self.mask_box[0]))
            if self.mask.shape != size:
                raise ValueError(f"mask must have mask_box's size {size}, got {self.mask.shape}")

    def mask_in(self, box) -> np.ndarray | None:
        """The mask resampled to another integer box (zeros outside the own mask box), or None."""
        if self.mask is None:
            return None
        return mask_in_region(self.mask, self.mask_box[:2], as_box(box))

    def full_mask(self, frame_size: tuple[int, int]) -> np.ndarray:
        """(H, W) bool mask over the whole frame (all False without a mask)."""
        height, width = frame_size
        if self.mask is None:
            return np.zeros((height, width), dtype=bool)
        return self.mask_in((0, 0, width, height))


@dataclass
class FrameContext:
    """The frame every estimator of one step sees: image (H, W, 3) uint8 RGB, its index in the video, and a
    scratch cache for estimators that share work within the frame (e.g. one MediaPipe run serving the
    segmenter and the 2D pose estimator)."""

    image: np.ndarray
    index: int
    cache: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.image.ndim != 3 or self.image.shape[2] != 3 or self.image.dtype != np.uint8:
            raise ValueError(f"image must be (H, W, 3) uint8 RGB, got shape {self.image.shape} dtype "
                             f"{self.image.dtype}")

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return int(self.image.shape[0]), int(self.image.shape[1])
