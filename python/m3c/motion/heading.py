"""Walkers face where they walk: a lifted track's heading turned to the direction its pelvis moves, before the
world optimization (its start and the reference of its heading_anchor term).

A camera-local fit sees which way a person faces poorly from behind or in front (turning the body about the
vertical barely moves the keypoints), while the direction the person travels comes from the whole trajectory.
On the video benchmark's steady walkers (Bandai Namco's walks, seed 1) the fitted facing was 17.5 degrees off the
truth (median over walking frames; 48 at the 90th percentile) and the lift's direction of travel, a line fit over
+- 1 s of the pelvis, 2.5 (7.5); the truth's walkers face within 5 degrees of where they go. So in a track whose
feet alternate steadily (m3c.eval.plausibility.gait_figures of its lifted joints), each frame moving faster than
min_speed is turned about the ground normal, through the root joint, to face its direction of travel, unless
that turn exceeds max_turn_deg (a side step, a walk backwards, a look over the shoulder are left alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body.transform import facing_directions
from m3c.eval.plausibility import PELVIS, gait_figures
from m3c.perception.contacts import local_velocities


@dataclass
class WalkingHeadingConfig:
    enabled: bool = True
    min_speed: float = 0.6      # m/s of the pelvis (line fit over +- half_window_s) for a frame to count as walking
    max_turn_deg: float = 45.0  # larger disagreements between facing and travel are left as fitted
    half_window_s: float = 1.0

    def validate(self) -> None:
        if not (math.isfinite(self.min_speed) and self.min_speed >= 0):
            raise ValueError(f"walking_heading.min_speed must be a number >= 0 (m/s), got {self.min_speed!r}")
        if not (math.isfinite(self.max_turn_deg) and 0 <= self.max_turn_deg <= 180):
            raise ValueError(f"walking_heading.max_turn_deg must lie in [0, 180], got {self.max_turn_deg!r}")
        if not (math.isfinite(self.half_window_s) and self.half_window_s > 0):
            raise ValueError(f"walking_heading.half_window_s must be a number > 0 (seconds), got "
                             f"{self.half_window_s!r}")


def turn_to_walking_direction(model, root_orient: np.ndarray, body_pose: np.ndarray, betas: np.ndarray,
                              transl: np.ndarray, up: np.ndarray, times: np.ndarray,
                              config: WalkingHeadingConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(root_orient (n, 3) axis-angle with each walking frame turned to face its direction of travel, the turn in
    radians per frame (0 where left alone)) for one track's world bodies: root_orient (n, 3), body_pose (n, J-1, 3),
    betas (B,), transl (n, 3), up (3,) the ground normal, times (n,) seconds (increasing)."""
    config = config or WalkingHeadingConfig()
    config.validate()
    root_orient = np.asarray(root_orient, dtype=np.float64)
    n = len(root_orient)
    turn = np.zeros(n)
    if not config.enabled or n < 2:
        return root_orient, turn
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    times = np.asarray(times, dtype=np.float64)
    pose = np.concatenate([root_orient[:, None], np.asarray(body_pose, dtype=np.float64)], axis=1)
    joints = model.joints(pose, np.asarray(betas, dtype=np.float64), np.asarray(transl, dtype=np.float64))
    pelvis = joints[:, list(PELVIS)].mean(axis=1)
    velocity = local_velocities(pelvis[:, None], times, config.half_window_s)[:, 0]
    velocity -= np.outer(velocity @ up, up)
    speed = np.linalg.norm(velocity, axis=1)
    fps = (n - 1) / (times[-1] - times[0])
    if gait_figures(joints, fps, np.tile(up, (n, 1)), float(speed.mean()))["step_rate_spm"] is None:
        return root_orient, turn
    facing = facing_directions(joints, up)
    travel = velocity / np.maximum(speed, 1e-12)[:, None]
    angle = np.arctan2(np.cross(facing, travel) @ up, np.einsum("ni,ni->n", facing, travel))
    walking = (speed > config.min_speed) & (np.abs(angle) <= math.radians(config.max_turn_deg)) & \
        (np.linalg.norm(facing, axis=1) > 0)
    turn[walking] = angle[walking]
    turned = Rotation.from_rotvec(np.outer(turn, up)) * Rotation.from_rotvec(root_orient)
    return turned.as_rotvec(), turn
