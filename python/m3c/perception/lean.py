"""People leaned to the scene's vertical: a track's camera-local bodies re-fitted so that, over the track, they
lean towards the camera as much as the scene's vertical says an upright person does.

A monocular fit barely sees how far a person leans towards the camera (it foreshortens the body by cos(lean)),
and MediaPipe's metric landmarks, which hold the fit's orientation, lean people less towards a camera looking
down than it looks: on the video benchmark's cameras 26-42 degrees down the fitted spine leaned 10-21 degrees away
from the scene's vertical (median over each track), on its other cameras 0-12. A body leaning away projects
longer, so the fit places it further: the high cameras' people stood 9-21% too far. Where the scene's vertical
edges give the up direction in every frame's camera (m3c.ground.world_frame.scene_up_prior, the same prior the
ground's tilt takes), each track's median lean towards the camera (pelvis-to-neck, in the vertical plane through
the camera) is measured against it, and a track leaning away from the camera by more than min_lean (and less
than max_lean) is re-fitted by the per-frame fit of m3c.perception.body (cpp/fit): its 2D
keypoints, and as the 3D observation its own fitted keypoints turned about the hips by the missing lean
(about the horizontal axis across the line of sight), so the body pose keeps its shape while the 2D keypoints
decide its depth and limbs at the new lean. Every frame is turned by the track's one angle: a person who bends
over or leans into a turn keeps doing so. Only leans away from the camera are corrected, the direction of the
landmarks' bias (86 of the 88 re-fits on the video benchmark's seeds 0-5 and walkers 0-1 leaned away): a person
bent towards the camera is real more often than not (the basketball clip's dribbler: +17 degrees).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body.transform import spine_directions
from m3c.perception.body import HIPS, RESTART_GAP, BodyFitConfig, cold_starts, fit_bodies, keypoint_regressor


@dataclass
class LeanConfig:
    """Settings of releaned_track. min_lean, max_lean: degrees of the track's median lean away from the camera
    between which it is re-fitted; max_up_sigma: degrees, the forward uncertainty of the scene's up (scene_up_prior) above
    which no track is touched; keypoints3d_weight: the re-fit's weight on the turned body (BodyFitConfig's, per m^2;
    higher holds the turned lean harder against the 2D keypoints: 1000 moved the high cameras' people to within
    2-7 degrees of upright at 1.1-1.8 px of reprojection error); restart_gap: frames without a fit after which the
    re-fit starts cold (perception's)."""

    enabled: bool = True
    min_lean: float = 2.0
    max_lean: float = 25.0
    max_up_sigma: float = 5.0
    keypoints3d_weight: float = 1000.0
    restart_gap: int = RESTART_GAP

    def validate(self) -> None:
        if not (0 <= self.min_lean < self.max_lean <= 90):
            raise ValueError(f"lean: need 0 <= min_lean < max_lean <= 90 degrees, got {self.min_lean}, "
                             f"{self.max_lean}")
        if not (self.max_up_sigma > 0 and self.keypoints3d_weight > 0 and self.restart_gap >= 0):
            raise ValueError("lean: max_up_sigma and keypoints3d_weight must be > 0 and restart_gap >= 0, got "
                             f"{self.max_up_sigma}, {self.keypoints3d_weight}, {self.restart_gap}")


def towards_camera(joints: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lean (n,) degrees, axis (n, 3)) of camera-frame SMPL joints (n, J, 3) against the up direction in each
    frame's camera (n, 3) or (3,): the spine's angle from up in the vertical plane through the camera and the
    pelvis, positive leaning towards the camera; axis: unit up x (the horizontal direction towards the camera),
    about which a turn by +a degrees (right-handed) raises the lean by a."""
    joints = np.asarray(joints, dtype=np.float64)
    up = np.broadcast_to(np.asarray(up, dtype=np.float64), (len(joints), 3))
    up = up / np.linalg.norm(up, axis=1, keepdims=True)
    spine = spine_directions(joints)
    ray = joints[:, 0] / np.linalg.norm(joints[:, 0], axis=1, keepdims=True)
    toward = -(ray - np.einsum("ni,ni->n", ray, up)[:, None] * up)
    toward /= np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-12)
    lean = np.degrees(np.arctan2(np.einsum("ni,ni->n", spine, toward), np.einsum("ni,ni->n", spine, up)))
    return lean, np.cross(up, toward)


def releaned_track(model, track: dict, up: np.ndarray, intrinsics, config: LeanConfig | None = None
                   ) -> tuple[dict, dict]:
    """(the track re-fitted upright, a record) for one perception track (m3c.perception.handover: frame, keypoints,
    pose, betas, transl in the camera) with the up direction up (n, 3) in each of its frames' camera; the track
    itself where it leans away from the camera by less than min_lean or more than max_lean, or towards it
    (record["refit"] False, with the reason)."""
    config = config or LeanConfig()
    config.validate()
    if "transl" not in track:
        return track, {"refit": False, "reason": "no camera-frame bodies"}
    pose = np.asarray(track["pose"], dtype=np.float64)
    betas = np.asarray(track["betas"], dtype=np.float64)
    transl = np.asarray(track["transl"], dtype=np.float64)
    joints = model.joints(pose, betas, transl)
    lean, axis = towards_camera(joints, up)
    median = float(np.median(lean))
    record = {"refit": False, "lean_before": median, "lean_after": median, "turn": 0.0}
    if not config.min_lean <= -median <= config.max_lean:
        record["reason"] = (f"leans {median:+.1f} degrees towards the camera (re-fitted between -{config.max_lean:g} "
                            f"and -{config.min_lean:g})")
        return track, record
    keypoints = np.asarray(track["keypoints"], dtype=np.float64)
    turn = -median
    fitted = model.keypoints(keypoint_regressor(model, keypoints.shape[1]), pose, betas, transl)
    hips = fitted[:, list(HIPS)].mean(axis=1, keepdims=True)
    turned = Rotation.from_rotvec(math.radians(turn) * axis)
    observed = np.zeros(keypoints.shape[:2] + (4,))
    for i in range(len(pose)):
        observed[i, :, :3] = turned[i].apply(fitted[i] - hips[i])
    observed[..., 3] = 1.0
    frames = np.asarray(track["frame"], dtype=np.int64)
    fits = fit_bodies(model, keypoints, intrinsics, observed, cold_starts(frames, config.restart_gap),
                      BodyFitConfig(keypoints3d_weight=config.keypoints3d_weight), times=frames)
    ok = fits.valid
    new = dict(track, pose=np.where(ok[:, None, None], fits.pose, pose),
               betas=np.where(ok[:, None], fits.betas, betas), transl=np.where(ok[:, None], fits.transl, transl))
    after, _ = towards_camera(model.joints(new["pose"], new["betas"], new["transl"]), up)
    record.update(refit=True, lean_after=float(np.median(after)), turn=turn,
                  depth_ratio=float(np.median(new["transl"][:, 2] / transl[:, 2])),
                  reprojection_px=float(np.median(fits.reprojection_error_px[ok])) if ok.any() else None)
    return new, record
