"""One estimator interface per perception task (thesis 4.1.1-4.1.3). Implementations register under a name
(m3c.perception.registry) and are chosen by name in the pipeline's config; every result records the name of
the estimator that produced it (Person.sources, the track's `estimators`)."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from m3c.perception.types import FrameContext, Person

TASKS = ("detector", "segmenter", "pose2d", "body", "contacts", "depth", "gender")
GENDERS = ("neutral", "male", "female")


class Estimator(ABC):
    task: str = ""
    name: str = ""  # set by the registry when it creates the estimator

    def close(self) -> None:
        """Releases what the estimator holds (models, graphs); the default holds nothing."""


class Detector(Estimator):
    """Frame -> people boxes with scores. A detector may fill more (mask, keypoints) when its model gives them,
    recording itself in Person.sources for each part. `known` people (already found in this frame, e.g. by
    tracking) need not be found again; a detector may use them to search only the rest of the frame."""

    task = "detector"

    @abstractmethod
    def detect(self, ctx: FrameContext, known: list[Person] | None = None) -> list[Person]:
        ...

    def skeletons(self, ctx: FrameContext) -> list[np.ndarray]:
        """The people (17, 3) a multi-person pose network saw in this frame, when detect ran one on it (the
        pipeline keeps a tracked person its pose search lost on them); none by default."""
        return []


class Segmenter(Estimator):
    """Frame + people -> the same people with masks (Person.mask / mask_box)."""

    task = "segmenter"

    @abstractmethod
    def segment(self, ctx: FrameContext, people: list[Person]) -> list[Person]:
        ...


class PoseEstimator2D(Estimator):
    """Frame + people -> COCO-17 keypoints per person (and root-relative 3D keypoints when the model gives
    them); None where nobody is found in a person's patch."""

    task = "pose2d"

    @abstractmethod
    def estimate(self, ctx: FrameContext, people: list[Person]) -> list[Person | None]:
        ...


class BodyEstimator(Estimator):
    """One track's keypoints -> camera-local body model parameters per frame (in `model`'s parameters).

    An estimator that reads pixels (reads_images = True, e.g. HMR 2.0) is also shown every frame's people
    (`observe`); what it returns for each person is handed back to fit_track as `observations`, in the track's
    frame order."""

    task = "body"
    model = None  # the m3c.body.BodyModel the fits belong to
    reads_images = False

    def observe(self, ctx: FrameContext, people: list[Person]) -> list:
        """Per-person results from the frame's pixels (one item per person, None where there is none)."""
        raise NotImplementedError(f"the body estimator {self.name!r} does not read images")

    @abstractmethod
    def fit_track(self, keypoints: np.ndarray, keypoints3d: np.ndarray | None, intrinsics: np.ndarray,
                  restart: np.ndarray | None = None, times: np.ndarray | None = None):
        ...


class ContactEstimator(Estimator):
    """One track's SMPL joints (n, 24, 3) at frame_ids / fps -> contact probabilities (n, 4) of
    m3c.body.joint_names.CONTACT_JOINTS; up None = estimated; ground_static: the joints' frame does not move with the
    ground (world, static camera); rest_heights: (4,) the joints' heights above the sole when standing;
    ground_speeds: (n, 4) m/s of the joints against the ground under them, NaN where unknown, or None.
    for_ground: the feet that surely stand on the ground (the ground planes and the camera scale are fitted to
    them), rather than every planted foot (which the optimizer holds still)."""

    task = "contacts"

    @abstractmethod
    def estimate(self, joints: np.ndarray, fps: float, up: np.ndarray | None, ground_static: bool,
                 frame_ids: np.ndarray | None = None, rest_heights: np.ndarray | None = None,
                 ground_speeds: np.ndarray | None = None, for_ground: bool = False) -> np.ndarray:
        ...


class DepthEstimator(Estimator):
    """Frame -> relative depth map (H, W) float32, or None when depth is not estimated."""

    task = "depth"

    @abstractmethod
    def estimate(self, ctx: FrameContext) -> np.ndarray | None:
        ...


class GenderEstimator(Estimator):
    """One track's people -> "neutral", "male" or "female"."""

    task = "gender"

    @abstractmethod
    def estimate(self, track_id: int, people: list[Person]) -> str:
        ...


INTERFACES = {cls.task: cls for cls in (Detector, Segmenter, PoseEstimator2D, BodyEstimator, ContactEstimator,
                                        DepthEstimator, GenderEstimator)}
