"""MediaPipe Hands (the legacy mp.solutions.hands; its palm detector and hand_landmark_full.tflite ship inside
the mediapipe==0.10.14 wheel, nothing is downloaded) on a crop around each of a person's wrists.

The crop is a square centred a little beyond the wrist along the forearm (the COCO-17 elbow -> wrist
direction), its side twice the forearm or the torso's length, whichever is longer (at least MIN_CROP px),
upsampled to CROP_SIZE px for the detector. Every hand found in it is a candidate for that wrist; the one kept
is the closest by its wrist landmark, within MAX_MATCH_DISTANCE reaches (wrist_crop), with a penalty when
MediaPipe's handedness disagrees. MediaPipe labels handedness for mirrored (selfie) images: its "Left" is the
person's right hand in an ordinary video. When both wrists keep the same hand (hands close together), the
better match keeps it.

Per hand and frame: 21 landmarks (u, v in frame pixels, confidence), MediaPipe's order (m3c.body.hands.
MEDIAPIPE_HAND_NAMES); the confidence is the detector's hand score, the same for the 21.
"""

from __future__ import annotations

import numpy as np

from m3c.perception.mediapipe_pose import _quiet, import_mediapipe

CROP_SIZE = 256
MIN_CROP = 24.0
MAX_MATCH_DISTANCE = 0.6  # forearm lengths between the body's wrist and the hand's wrist landmark
HANDEDNESS_PENALTY = 0.3  # forearm lengths added when MediaPipe's handedness disagrees (times its score)
COCO_WRIST = {"left": 9, "right": 10}
COCO_ELBOW = {"left": 7, "right": 8}
MIN_KEYPOINT_CONFIDENCE = 0.3


class MediaPipeHands:
    """One mp.solutions.hands graph in static-image mode (every run detects palms, then finds landmarks)."""

    def __init__(self, min_detection_confidence: float = 0.4, max_num_hands: int = 2):
        mp = import_mediapipe()
        with _quiet():
            self._hands = mp.solutions.hands.Hands(static_image_mode=True, max_num_hands=max_num_hands,
                                                   model_complexity=1,
                                                   min_detection_confidence=min_detection_confidence)
        self.runs = 0

    def run(self, rgb: np.ndarray) -> list[tuple[np.ndarray, str, float]]:
        """Hands in an RGB image: (landmarks 21 x 2 in its pixels, MediaPipe's handedness label, score) each.
        MediaPipe's x, y are fractions of the width and height from the image's edges, which M3C's pixel
        convention (pixel centres at integers) puts at -0.5."""
        h, w = rgb.shape[:2]
        with _quiet():
            result = self._hands.process(np.ascontiguousarray(rgb))
        self.runs += 1
        hands = []
        for landmarks, handedness in zip(result.multi_hand_landmarks or [], result.multi_handedness or []):
            points = np.array([[p.x * w - 0.5, p.y * h - 0.5] for p in landmarks.landmark])
            label = handedness.classification[0]
            hands.append((points, label.label, float(label.score)))
        return hands

    def close(self) -> None:
        self._hands.close()


def wrist_crop(keypoints: np.ndarray, side: str) -> tuple[np.ndarray, float] | None:
    """(square box x0, y0, x1, y1 in frame pixels, reach px) around a wrist of COCO-17 keypoints (17 x 3), or
    None when the wrist or elbow is not confident. The reach is the forearm's length in the image, at least
    half the torso's (shoulders' to hips' midpoints, when confident: a forearm pointing at the camera looks
    short)."""
    wrist, elbow = keypoints[COCO_WRIST[side]], keypoints[COCO_ELBOW[side]]
    if not (wrist[2] >= MIN_KEYPOINT_CONFIDENCE and elbow[2] >= MIN_KEYPOINT_CONFIDENCE):
        return None
    forearm = wrist[:2] - elbow[:2]
    length = float(np.linalg.norm(forearm))
    if not np.isfinite(length):
        return None
    reach = length
    if np.all(keypoints[[5, 6, 11, 12], 2] >= MIN_KEYPOINT_CONFIDENCE):
        torso = np.linalg.norm(keypoints[[5, 6], :2].mean(axis=0) - keypoints[[11, 12], :2].mean(axis=0))
        reach = max(reach, 0.5 * float(torso))
    if reach < 1.0:
        return None
    centre = wrist[:2] + 0.35 * forearm * (reach / max(length, 1e-6) if length > 1.0 else 0.0)
    half = max(reach, MIN_CROP / 2)
    return np.array([centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half]), reach


def crop_square(frame_rgb: np.ndarray, box: np.ndarray, size: int = CROP_SIZE) -> tuple[np.ndarray, float]:
    """The box (may reach outside the frame: grey there) resampled to size x size; returns (crop, pixels of
    the frame per crop pixel)."""
    import cv2

    scale = (box[2] - box[0]) / size
    # The box's edges in frame coordinates (pixel centres at integers): crop pixel i's centre is at frame
    # box[0] + (i + 0.5) * scale.
    M = np.array([[scale, 0.0, box[0] + 0.5 * scale], [0.0, scale, box[1] + 0.5 * scale]])
    crop = cv2.warpAffine(frame_rgb, M, (size, size), flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(128, 128, 128))
    return crop, scale


def person_side(label: str) -> str:
    """MediaPipe's handedness label (mirrored-image convention) -> the person's side (unmirrored video)."""
    return "right" if label == "Left" else "left"


def match_hands(candidates: dict, wrists: dict, forearms: dict) -> dict:
    """candidates: side -> [(landmarks 21 x 2 frame px, label, score)] found in that wrist's crop; wrists:
    side -> the body's wrist (2,) px; forearms: side -> forearm length px. Returns side -> (landmarks, score)
    for the matched hands (module docstring)."""
    best = {}
    for side, found in candidates.items():
        for landmarks, label, score in found:
            distance = np.linalg.norm(landmarks[0] - wrists[side]) / forearms[side]
            cost = distance + (HANDEDNESS_PENALTY * score if person_side(label) != side else 0.0)
            if distance <= MAX_MATCH_DISTANCE and (side not in best or cost < best[side][0]):
                best[side] = (cost, landmarks, score)
    if len(best) == 2:
        (cl, left, _), (cr, right, _) = best["left"], best["right"]
        size = min(np.linalg.norm(left[9] - left[0]), np.linalg.norm(right[9] - right[0]))
        if np.mean(np.linalg.norm(left - right, axis=1)) < 0.3 * max(size, 1.0):  # one hand, kept twice
            del best["right" if cr > cl else "left"]
    return {side: (landmarks, score) for side, (_, landmarks, score) in best.items()}


def detect_hands(engine: MediaPipeHands, frame_rgb: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """21 x 3 landmarks (u, v, confidence) per side (2 x 21 x 3; NaN where no hand) of one person in one
    frame, from their COCO-17 keypoints (17 x 3)."""
    out = np.full((2, 21, 3), np.nan)
    candidates, wrists, forearms = {}, {}, {}
    for side in ("left", "right"):
        crop_box = wrist_crop(keypoints, side)
        if crop_box is None:
            continue
        box, forearms[side] = crop_box
        wrists[side] = keypoints[COCO_WRIST[side], :2]
        crop, scale = crop_square(frame_rgb, box)
        candidates[side] = [(box[:2] + (points + 0.5) * scale, label, score)
                            for points, label, score in engine.run(crop)]
    for side, (landmarks, score) in match_hands(candidates, wrists, forearms).items():
        s = 0 if side == "left" else 1
        out[s, :, :2] = landmarks
        out[s, :, 2] = score
    return out
