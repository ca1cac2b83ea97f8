"""The hands node: each final track's hands, found by MediaPipe Hands around its wrists
(m3c.perception.hands), fitted per frame to the final body's wrists (m3c.perception.hand_fit), then over
the track's whole time (m3c.perception.hand_track: every frame's fingers and wrist correction in one solve
per hand and run of frames, reprojection of the 21 landmarks through the world cameras, temporal
smoothness, joint limits; the body fixed). Gaps of up to TrackWeights.max_gap frames inside a run are
interpolated by that solve.

Output hands: enabled, reason (why it is off, or None), seconds, frames (frames with a person), hand_frames
(hands fitted), tracks (per final track: track_id, first_frame, num_frames, keypoints n x 2 x 21 x 3 (u, v,
confidence; MediaPipe's order; NaN where no hand), hand_pose n x 2 x 15 x 3 (SMPL-H finger pose, NaN where
none), wrist_correction n x 2 x 3 (the wrists' refined rotation: world R_wrist @ exp(c), NaN where none)).
The body's world optimization does not see the hands: the hand solve runs on its result and leaves its body
(body_pose keeps the optimizer's wrists; the wrist correction only serves the finger fit).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from m3c.camera import WorldCameras
from m3c.ground.tracks import track_poses
from m3c.nodes.frames import stream_frames
from m3c.pipeline import Node, register_node

LOG = logging.getLogger("m3c.nodes.hands")


def disabled(reason: str) -> dict:
    return {"hands": {"enabled": False, "reason": reason, "seconds": 0.0, "frames": 0, "hand_frames": 0,
                      "tracks": []}}


@register_node
class HandsNode(Node):
    type_name = "hands"
    level = "track"
    inputs = ("video", "camera", "result")
    outputs = ("hands",)
    settings = ("body_model",)
    nonfinite_outputs = ("hands.tracks[].keypoints", "hands.tracks[].hand_pose",
                         "hands.tracks[].wrist_correction")

    # 2: the track-level hand solve (m3c.perception.hand_track) replaces the Gaussian smoothing by default.
    version = "2"

    @dataclass
    class Config:
        enabled: bool = True  # --no-hands: false
        min_detection_confidence: float = 0.4  # MediaPipe's palm detector
        track_fit: bool = True  # the fingers over each track's whole time (m3c.perception.hand_track)
        # Without track_fit: Gaussian sigma of the per-frame fits' temporal smoothing (frames); 0: none
        smoothing_frames: float = 1.5

    def run(self, ctx, inputs):
        if not self.config.enabled:
            return disabled("off (hands.enabled: false, --no-hands)")
        from m3c.body.hands import hand_model_for
        from m3c.perception.mediapipe_pose import mediapipe_available

        model = ctx.loaded("body_model")
        hand = hand_model_for(model.data.name)
        if hand is None:
            return disabled(f"no hand model for the body model {model.data.name} (only M3C's open model has "
                            "one)")
        if not mediapipe_available():
            LOG.warning("hands: MediaPipe is not installed (pip install 'm3c[perception]'); no hands")
            return disabled("MediaPipe is not installed")
        return {"hands": track_hands(ctx, model, hand, inputs["video"], inputs["camera"], inputs["result"],
                                     self.config)}


def track_hands(ctx, model, hand, video: dict, camera: dict, result: dict, config) -> dict:
    import cv2

    from m3c.body.hands import SIDES, wrist_frames
    from m3c.perception.hand_fit import NUM_DOFS, SideModel, dofs_to_pose, fit_hand, smooth_dofs
    from m3c.perception.hand_track import fit_hand_track
    from m3c.perception.hands import MediaPipeHands, detect_hands

    start = time.time()
    tracks = result["tracks"]
    intrinsics = np.asarray(camera["intrinsics"], dtype=np.float64)
    world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
    state = []
    for track in tracks:
        n, betas = int(track["num_frames"]), np.asarray(track["betas"], dtype=np.float64)
        rotation, position = wrist_frames(model, track_poses(track), betas, np.asarray(track["transl"]))
        state.append(dict(
            n=n, first=int(track["first_frame"]), keypoints=np.asarray(track["keypoints"], dtype=np.float64),
            rotation=rotation, position=position, sides=[SideModel(hand, betas, s) for s in SIDES],
            landmarks=np.full((n, 2, 21, 3), np.nan), dofs=np.full((n, 2, NUM_DOFS + 3), np.nan),
            previous=[None, None]))
    engine = MediaPipeHands(min_detection_confidence=config.min_detection_confidence)
    frames = 0
    try:
        with ctx.progress("finding hands", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                rgb = None
                for s in state:
                    k = i - s["first"]
                    if not 0 <= k < s["n"]:
                        continue
                    frames += 1
                    rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB) if rgb is None else rgb
                    found = detect_hands(engine, rgb, s["keypoints"][k])
                    s["landmarks"][k] = found
                    for side in range(2):
                        fit = None
                        if np.isfinite(found[side, 0, 0]):
                            fit = fit_hand(s["sides"][side], found[side], s["rotation"][k, side],
                                           s["position"][k, side], world_from_cam[i], intrinsics,
                                           previous=s["previous"][side])
                        s["previous"][side] = fit
                        if fit is not None:
                            s["dofs"][k, side] = np.r_[fit.dofs, fit.wrist_correction]
                bar.update()
    finally:
        engine.close()
    out_tracks, hand_frames = [], 0
    for track, s in zip(tracks, state):
        hand_pose = np.full((s["n"], 2, 15, 3), np.nan)
        correction = np.full((s["n"], 2, 3), np.nan)
        span = slice(s["first"], s["first"] + s["n"])
        for side in range(2):
            values = s["dofs"][:, side]
            if config.track_fit:
                values = fit_hand_track(s["sides"][side], s["landmarks"][:, side], s["rotation"][:, side],
                                        s["position"][:, side], world_from_cam[span], intrinsics, values)
            found = np.isfinite(values[:, 0])
            hand_frames += int(found.sum())
            if not config.track_fit and config.smoothing_frames > 0:
                values = smooth_dofs(np.nan_to_num(values), found, config.smoothing_frames)
            hand_pose[found, side] = dofs_to_pose(values[found, :NUM_DOFS], s["sides"][side].axes)
            correction[found, side] = values[found, NUM_DOFS:]
        out_tracks.append({"track_id": int(track["track_id"]), "first_frame": s["first"],
                           "num_frames": s["n"], "keypoints": s["landmarks"], "hand_pose": hand_pose,
                           "wrist_correction": correction})
    seconds = time.time() - start
    LOG.info("hands: %d hands fitted in %d person-frames, %.2f s (%.3f s per frame)", hand_frames, frames,
             seconds, seconds / max(video["num_frames"], 1))
    return {"enabled": True, "reason": None, "seconds": seconds, "frames": frames, "hand_frames": hand_frames,
            "tracks": out_tracks}


def corrected_body_pose(body_pose: np.ndarray, wrist_correction: np.ndarray) -> np.ndarray:
    """body_pose n x 23 x 3 (SMPL joints 1..23) with the wrists' local rotations refined by the hand fit: the
    wrist's world rotation R_w becomes R_w exp(c), so its local rotation L becomes L exp(c). Frames without a
    fit (NaN) keep theirs."""
    from scipy.spatial.transform import Rotation

    from m3c.body.hands import SIDES, WRIST_JOINTS

    out = np.array(body_pose, dtype=np.float64, copy=True)
    for s, side in enumerate(SIDES):
        c = wrist_correction[:, s]
        ok = np.isfinite(c).all(axis=1)
        if ok.any():
            j = WRIST_JOINTS[side] - 1
            local = Rotation.from_rotvec(out[ok, j]) * Rotation.from_rotvec(c[ok])
            out[ok, j] = local.as_rotvec()
    return out
