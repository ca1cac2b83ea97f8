"""Contacts without BSTRO: per-joint contact probabilities from kinematics, feeding the ground stage.

A foot point touches the ground when it is near the local ground and (in a frame where the ground does not
move: the world, or a static camera) nearly still:
  p = sigmoid((h0 - h) / h_soft) * sigmoid((v0 - v) / v_soft),
with h the point's height above the local ground and v its speed. Heights are measured along `up` and
corrected by each point's height above the sole when standing (rest_heights: an ankle sits higher than a toe
base); the local ground is the ground_quantile of the corrected heights of all foot points within
+- window_seconds. Speeds are the slopes of least-squares lines through the positions within
+- speed_window_seconds, so per-frame jitter of a monocular fit does not read as motion. Where the speeds of the
feet against the ground are given (ground_speeds: m3c.perception.ground_motion reads them from the images), they
take the place of v in any camera; otherwise, in a moving camera's frame (ground_static=False) the speed factor is
left out and heights alone decide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.body import BodyModel
from m3c.ground import ContactTrack, foot_vertex_ids
from m3c.body.joint_names import CONTACT_JOINTS
from m3c.body.transform import facing_directions, spine_directions
from m3c.perception.interfaces import ContactEstimator
from m3c.perception.registry import register

NAME = "kinematic"
PELVIS = 0


@dataclass
class KinematicContactConfig:
    height_threshold: float = 0.05   # metres above the local ground where the height factor is 0.5
    height_softness: float = 0.015
    speed_threshold: float = 0.5     # m/s where the speed factor is 0.5 (monocular fits jitter)
    speed_softness: float = 0.15
    # Where the feet's speeds against the ground are read from the images (ground_speeds), they decide: their
    # threshold is higher (they carry the 2D keypoints' jitter) and the height factor only rules out a foot well
    # off the ground, as a monocular fit's heights in a moving camera are noisy (tuned on the video benchmark's
    # seed 0, checked on seed 1: agreement with the true contacts 0.56 -> 0.82).
    ground_speed_threshold: float = 1.5
    ground_speed_height_threshold: float = 0.2
    # In a moving camera's frame (no foot speeds against the ground), a foot that moves forward relative to the
    # body faster than facing_speed_threshold is swinging: a planted foot moves backwards relative to a walker's
    # body, at his speed, whatever the camera does. That rule decides there, with the looser
    # facing_height_threshold (None: heights alone). Tuned on the video benchmark's seed 0 (agreement of the feet
    # with the true contacts: precision 0.80 -> 0.81, recall 0.44 -> 0.77 over seeds 0 and 1), checked on seed 1.
    facing_speed_threshold: float | None = 0.4
    facing_height_threshold: float = 0.15
    window_seconds: float = 1.0
    speed_window_seconds: float = 0.1
    root_window_seconds: float | None = None  # see kinematic_contacts(root=...); None: plain foot speeds
    ground_quantile: float = 0.1

    def __post_init__(self):
        if min(self.height_softness, self.speed_softness, self.window_seconds, self.speed_window_seconds,
               self.root_window_seconds or 1.0) <= 0:
            raise ValueError("softness and window lengths must be > 0")
        if not 0 <= self.ground_quantile <= 1:
            raise ValueError("ground_quantile must be in [0, 1]")


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def estimate_up(joints: np.ndarray) -> np.ndarray:
    """The up direction (3,) as the mean pelvis-to-neck direction of SMPL joints (n, 24, 3): people are mostly
    upright, and this works in any frame (camera or world)."""
    up = spine_directions(joints).mean(axis=0)
    norm = np.linalg.norm(up)
    if norm < 1e-6:
        raise ValueError("cannot tell up from the joints (the spine directions cancel out); pass `up`")
    return up / norm


def contact_rest_heights(model: BodyModel, betas=None) -> np.ndarray:
    """Heights (4,) of CONTACT_JOINTS above the sole (the lowest vertex) when standing in the rest pose; the
    model's rest pose is y-up."""
    betas = np.zeros(model.num_betas) if betas is None else np.asarray(betas, dtype=np.float64)
    out = model.forward(np.zeros((1, model.num_joints, 3)), betas)
    return out.joints[0, list(CONTACT_JOINTS), 1] - out.vertices[0, :, 1].min()


def time_windows(times: np.ndarray, half_window: float) -> tuple[np.ndarray, np.ndarray]:
    """Per frame t of the increasing `times`, the slice lo[t]:hi[t] that holds every frame within +- half_window
    seconds of it: a search in the sorted times instead of a test against the whole track (long tracks). The
    slice is a little wider, so that the callers' test |t' - t| <= half_window decides as it is written."""
    reach = half_window * (1 + 1e-9) + 1e-9
    return (np.searchsorted(times, times - reach, side="left"),
            np.searchsorted(times, times + reach, side="right"))


def local_velocities(points: np.ndarray, times: np.ndarray, half_window: float) -> np.ndarray:
    """Velocities (n, P, 3) of points (n, P, 3): the slope of a least-squares line through each point's
    positions at the times (increasing) within +- half_window (at least the two nearest neighbours)."""
    n = len(points)
    velocities = np.zeros(points.shape)
    lo, hi = time_windows(times, half_window)
    for t in range(n):
        near = lo[t] + np.flatnonzero(np.abs(times[lo[t]:hi[t]] - times[t]) <= half_window)
        if len(near) < 2:
            near = np.arange(max(t - 1, 0), min(t + 2, n))
        dt = times[near] - times[near].mean()
        denom = float(np.sum(dt ** 2))
        if denom > 0:
            velocities[t] = np.tensordot(dt, points[near] - points[near].mean(axis=0), axes=(0, 0)) / denom
    return velocities


def steady_depth(joints: np.ndarray, times: np.ndarray, half_window: float) -> np.ndarray:
    """Camera-frame joints (n, J, 3) (origin at the camera centre, +z forward, the root first), each frame's body
    moved along its root's line of sight to the median of the root depths within +- half_window seconds. Depth
    is what a monocular fit gets wrong from frame to frame (its body size along the ray); the move keeps the root
    where it is in the image and the body's own shape and motion relative to the root as they are (a scaling
    about the camera centre would keep the whole image, but it makes the relative motion jitter instead), and
    the median keeps the depth's real changes within the window. Frames whose root is not in front of the camera
    are left as they are. times: increasing seconds."""
    joints = np.asarray(joints, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    depth = joints[:, 0, 2]
    lo, hi = time_windows(times, half_window)
    steady = np.empty(len(depth))
    for t in range(len(depth)):
        near = depth[lo[t]:hi[t]]
        near = near[(np.abs(times[lo[t]:hi[t]] - times[t]) <= half_window) & (near > 0)]
        steady[t] = np.median(near) if len(near) else depth[t]
    stretch = np.where(depth > 0, steady / np.where(depth > 0, depth, 1.0) - 1.0, 0.0)
    return joints + (stretch[:, None] * joints[:, 0])[:, None]


def kinematic_contacts(points: np.ndarray, times: np.ndarray, up, ground_static: bool = True,
                       config: KinematicContactConfig | None = None, rest_heights=None,
                       root: np.ndarray | None = None, ground_speeds: np.ndarray | None = None,
                       facing: np.ndarray | None = None) -> np.ndarray:
    """Contact probabilities (n, P) of foot points (n, P, 3) metres at times (n,) seconds (increasing; gaps
    allowed), with up (3,) the up direction in the points' frame and rest_heights (P,) each point's height
    above the sole when standing (default 0).

    root: (n, 3) the body's root positions, or None. With it (and config.root_window_seconds set), a foot's
    velocity is its velocity relative to the root over speed_window_seconds plus the root's own over the longer
    root_window_seconds, which averages out a monocular fit's depth jitter (it moves the whole body at once) but
    also real changes of the body's speed within a stride: on the synthetic walkers it lowers the agreement with
    the true contacts, so it is off by default.

    ground_speeds: (n, P) m/s of each point against the ground under it (NaN where unknown), or None; where known
    it is the speed v of the speed factor, with config.ground_speed_threshold and ground_speed_height_threshold,
    whatever ground_static says.

    facing: (n, 3) the unit directions the body faces (m3c.body.transform.facing_directions), or None; with it, root
    and config.facing_speed_threshold, and ground_static False, v is each point's velocity relative to the root
    along the facing direction, with config.facing_height_threshold."""
    config = config or KinematicContactConfig()
    points = np.asarray(points, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"points must have shape (n, P, 3), got {points.shape}")
    n, P = points.shape[:2]
    if times.shape != (n,) or (n > 1 and np.any(np.diff(times) <= 0)):
        raise ValueError(f"times must be ({n},) and strictly increasing")
    if not np.isfinite(points).all():
        raise ValueError("points contain NaN/inf; drop those frames")
    rest = np.zeros(P) if rest_heights is None else np.asarray(rest_heights, dtype=np.float64)
    if rest.shape != (P,):
        raise ValueError(f"rest_heights must have shape ({P},), got {rest.shape}")
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    height = points @ up - rest
    ground = np.empty(n)
    lo, hi = time_windows(times, config.window_seconds)
    for t in range(n):
        window = np.abs(times[lo[t]:hi[t]] - times[t]) <= config.window_seconds
        ground[t] = np.quantile(height[lo[t]:hi[t]][window].ravel(), config.ground_quantile)
    above = height - ground[:, None]
    prob = _sigmoid((config.height_threshold - above) / config.height_softness)
    if ground_static and n >= 2:
        if root is None or config.root_window_seconds is None:
            velocity = local_velocities(points, times, config.speed_window_seconds)
        else:
            root = np.asarray(root, dtype=np.float64)
            if root.shape != (n, 3):
                raise ValueError(f"root must have shape ({n}, 3), got {root.shape}")
            velocity = (local_velocities(points - root[:, None], times, config.speed_window_seconds) +
                        local_velocities(root[:, None], times, config.root_window_seconds))
        speed = np.linalg.norm(velocity, axis=2)
        prob = prob * _sigmoid((config.speed_threshold - speed) / config.speed_softness)
    elif facing is not None and root is not None and config.facing_speed_threshold is not None and n >= 2:
        facing = np.asarray(facing, dtype=np.float64)
        if facing.shape != (n, 3):
            raise ValueError(f"facing must have shape ({n}, 3), got {facing.shape}")
        relative = local_velocities(points - np.asarray(root, dtype=np.float64)[:, None], times,
                                    config.speed_window_seconds)
        forward = (relative * facing[:, None]).sum(axis=2)
        prob = (_sigmoid((config.facing_height_threshold - above) / config.height_softness) *
                _sigmoid((config.facing_speed_threshold - forward) / config.speed_softness))
    if ground_speeds is not None:
        ground_speeds = np.asarray(ground_speeds, dtype=np.float64)
        if ground_speeds.shape != (n, P):
            raise ValueError(f"ground_speeds must have shape ({n}, {P}), got {ground_speeds.shape}")
        read = np.isfinite(ground_speeds)
        cue = (_sigmoid((config.ground_speed_height_threshold - above) / config.height_softness) *
               _sigmoid((config.ground_speed_threshold - np.nan_to_num(ground_speeds)) / config.speed_softness))
        prob = np.where(read, cue, prob)
    return prob


@register("contacts", NAME)
class KinematicContacts(ContactEstimator):
    """Contact probabilities of m3c.body.joint_names.CONTACT_JOINTS (ankles, feet) from a track's joints."""

    def __init__(self, **options):
        self.config = KinematicContactConfig(**options)

    def estimate(self, joints: np.ndarray, fps: float, up=None, ground_static: bool = True,
                 frame_ids: np.ndarray | None = None, rest_heights=None,
                 ground_speeds: np.ndarray | None = None, for_ground: bool = False) -> np.ndarray:
        """joints: (n, 24, 3) metres; frames at frame_ids / fps (default consecutive). up: None = from the
        spine. rest_heights: (4,) see contact_rest_heights (default 0). ground_speeds: (n, 4) m/s of the contact
        joints against the ground under them (see kinematic_contacts). for_ground: heights (and, in a ground-static
        frame, 3D speeds) alone, without the image and facing cues, whose looser height limits would spread the
        ground's points upwards. Returns (n, 4) probabilities for CONTACT_JOINTS."""
        joints = np.asarray(joints, dtype=np.float64)
        if joints.ndim != 3 or joints.shape[1:] != (24, 3):
            raise ValueError(f"joints must have shape (n, 24, 3), got {joints.shape}")
        if fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        frame_ids = np.arange(len(joints)) if frame_ids is None else np.asarray(frame_ids)
        up = estimate_up(joints) if up is None else up
        return kinematic_contacts(joints[:, list(CONTACT_JOINTS)], frame_ids / fps, up, ground_static, self.config,
                                  rest_heights, root=joints[:, PELVIS],
                                  ground_speeds=None if for_ground else ground_speeds,
                                  facing=None if for_ground else facing_directions(joints, up))


def sole_vertex_ids(model: BodyModel, sole_height: float = 0.02) -> np.ndarray:
    """Foot vertices (see m3c.ground.foot_vertex_ids) within sole_height metres of the lowest one in the rest
    pose (y-up): the soles, the part of a planted foot that touches the ground."""
    feet = foot_vertex_ids(np.asarray(model.data.weights))
    rest = model.forward(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas)).vertices[0]
    heights = rest[feet, 1]
    return feet[heights <= heights.min() + sole_height]


def contact_track(model: BodyModel, frame_ids, pose, betas, transl, contacts, threshold: float = 0.5,
                  sole_height: float = 0.02) -> ContactTrack:
    """The ground stage's input for one track: the sole vertices (sole_vertex_ids) whose contact joint (the
    CONTACT_JOINTS entry they are most weighted on) has probability > threshold.

    pose (n, 24, 3), betas (B,) or (n, B), transl (n, 3), contacts (n, 4); all in one frame (see
    m3c.ground.estimate_ground_planes on moving cameras)."""
    contacts = np.asarray(contacts, dtype=np.float64)
    n = len(pose)
    if contacts.shape != (n, len(CONTACT_JOINTS)):
        raise ValueError(f"contacts must have shape ({n}, {len(CONTACT_JOINTS)}), got {contacts.shape}")
    soles = sole_vertex_ids(model, sole_height)
    weights = np.asarray(model.data.weights)
    owner = np.argmax(weights[np.ix_(soles, list(CONTACT_JOINTS))], axis=1)
    vertices = model.keypoints(model.vertex_selection(soles), pose, betas, transl)
    prob = contacts[:, owner]  # (n, S)
    return ContactTrack.from_vertices(frame_ids, vertices, prob, np.arange(len(soles)), threshold)
