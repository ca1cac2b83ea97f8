"""Per-track ground planes over a video (the seed thesis, section 4.1.3, "Ground Estimation").

In every frame, the contact vertices (contact probability > 0.5) of all people are clustered with DBSCAN, a
plane is fitted to each cluster, and each person is associated with the plane closest to its contacts, feet
first. Only frames where a person's feet touch a plane count as observations; the other frames of its track
(a jump, a sit, a missed detection) are filled from them: the most recent observed plane ("hold") or an
interpolation ("linear").

Filling across frames assumes the planes are expressed in one frame over time (world coordinates, or a static
camera); with camera-frame points from a moving camera, transform them to the world frame first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from m3c import _core
from m3c.body.joint_names import CONTACT_JOINT_NAMES, SMPL_JOINT_NAMES
from m3c.ground.planes import GroundParams



def foot_vertex_ids(weights, joint_names: Sequence[str] = SMPL_JOINT_NAMES,
                    min_weight: float = 0.5) -> np.ndarray:
    """Sorted ids of the vertices whose skinning weights (V, J) on ankles and feet sum to >= min_weight."""
    weights = np.asarray(weights, dtype=np.float64)
    if weights.ndim != 2 or weights.shape[1] != len(joint_names):
        raise ValueError(f"weights must have shape (V, J={len(joint_names)}), got {weights.shape}")
    columns = [list(joint_names).index(name) for name in CONTACT_JOINT_NAMES]
    return np.flatnonzero(weights[:, columns].sum(axis=1) >= min_weight)


# A bound on the contact vertices placed per video: a plane fit and the soles' height saturate long before
# (each frame's points are one or two soles), and the points would otherwise grow with the video's length
# (about 1.2 million per minute of a walking clip, several float64 copies each in the ground node).
MAX_CONTACT_POINTS = 1_000_000


def track_poses(track: dict) -> np.ndarray:
    """(n, J, 3) axis-angle poses of a track dict: root_orient as joint 0, then body_pose."""
    return np.concatenate([np.asarray(track["root_orient"])[:, None], np.asarray(track["body_pose"])], axis=1)


def track_frames(track: dict) -> np.ndarray:
    """(n,) video frame indices of a track dict's frames."""
    return int(track["first_frame"]) + np.arange(int(track["num_frames"]))


def ground_contact_probabilities(track: dict) -> np.ndarray | None:
    """A track's contact probabilities (n, 4) of the feet surely on the ground, which the ground and the camera
    scale are fitted to: its ground_contacts where perception kept them apart from the planted feet, else its
    contacts; None without either."""
    return track.get("ground_contacts", track.get("contacts"))


def contact_vertices(model, tracks: Sequence[dict], threshold: float,
                     max_points: int = MAX_CONTACT_POINTS) -> list[list[np.ndarray]]:
    """Per track, per frame, its foot vertices in contact, in that frame's camera (metres, (k, 3) float64).

    tracks: camera-frame tracks (root_orient, body_pose, betas, transl, contacts (n, 4) over CONTACT_JOINT_NAMES,
    optionally ground_contacts (n, 4), which then decide, visible (n,)). A foot vertex is in contact when the foot
    joint that moves it most has probability > threshold in a visible frame. When all tracks together would place
    more than max_points points, every `step`-th foot vertex is kept (the same subset in every frame, spread over
    the soles; step the smallest that keeps the total within max_points), so the count stays bounded on a video of
    any length."""
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    foot_ids = foot_vertex_ids(model.data.weights)
    columns = [SMPL_JOINT_NAMES.index(name) for name in CONTACT_JOINT_NAMES]
    foot_joint = np.argmax(np.asarray(model.data.weights)[foot_ids][:, columns], axis=1)
    # The points the ground is fitted to: feet surely on the ground (the planted feet's looser height limits would
    # spread the points upwards).
    masks = [(ground_contact_probabilities(t) > threshold) & t["visible"][:, None]
             if "contacts" in t else None for t in tracks]
    per_joint = np.bincount(foot_joint, minlength=len(CONTACT_JOINT_NAMES))
    total = sum(int((m @ per_joint).sum()) for m in masks if m is not None)
    step = max(1, -(-total // max_points))
    foot_ids, foot_joint = foot_ids[::step], foot_joint[::step]
    out = []
    for track, in_contact in zip(tracks, masks):
        points = [np.zeros((0, 3)) for _ in range(track["num_frames"])]
        out.append(points)
        if in_contact is None:
            continue
        frames = np.flatnonzero(in_contact.any(axis=1))
        poses = track_poses(track)
        for chunk in np.array_split(frames, max(1, int(np.ceil(len(frames) / 64)))):
            if len(chunk) == 0:
                continue
            verts = model.forward(poses[chunk], track["betas"], track["transl"][chunk]).vertices[:, foot_ids]
            for k, i in enumerate(chunk):
                points[i] = verts[k][in_contact[i][foot_joint]]
    return out


@dataclass
class ContactTrack:
    """Contacts of one tracked person over its T frames.

    frame_ids: (T,) int, strictly increasing video frame ids; tracks sharing a frame id are clustered
        together in that frame.
    points: T arrays (M_t, 3) of contact vertex positions in metres (M_t may be 0), every track in the same
        coordinate frame.
    is_foot: T arrays (M_t,) bool, True for foot vertices.
    """

    frame_ids: np.ndarray
    points: list
    is_foot: list

    def __post_init__(self):
        self.frame_ids = np.asarray(self.frame_ids)
        if self.frame_ids.ndim != 1 or (self.frame_ids.size and self.frame_ids.dtype.kind not in "iu"):
            raise ValueError(f"frame_ids must be a (T,) integer array, got shape {self.frame_ids.shape} "
                             f"dtype {self.frame_ids.dtype}")
        self.frame_ids = self.frame_ids.astype(np.int64)
        T = len(self.frame_ids)
        if len(self.points) != T or len(self.is_foot) != T:
            raise ValueError(f"points and is_foot need one entry per frame id (T={T}), "
                             f"got {len(self.points)} and {len(self.is_foot)}")
        points, is_foot = [], []
        for t in range(T):
            p = np.asarray(self.points[t], dtype=np.float64)
            if p.size == 0:
                p = p.reshape(0, 3)
            if p.ndim != 2 or p.shape[1] != 3:
                raise ValueError(f"points[{t}] must have shape (M, 3), got {p.shape}")
            if not np.isfinite(p).all():
                raise ValueError(f"points[{t}] (frame {self.frame_ids[t]}) holds NaN or inf; "
                                 "drop those vertices")
            f = np.asarray(self.is_foot[t])
            if f.shape != (len(p),) or (f.size and f.dtype.kind not in "biu"):
                raise ValueError(f"is_foot[{t}] must be a bool array of shape ({len(p)},), "
                                 f"got shape {f.shape} dtype {f.dtype}")
            points.append(p)
            is_foot.append(f.astype(bool))
        self.points, self.is_foot = points, is_foot

    @classmethod
    def from_vertices(cls, frame_ids, vertices, contact_prob, foot_vertex_ids, threshold: float = 0.5):
        """Contacts from meshes: vertices (T, V, 3) metres, contact_prob (T, V) in [0, 1]; a vertex is in
        contact when its probability is > threshold; foot_vertex_ids lists the foot vertices (see
        foot_vertex_ids())."""
        vertices = np.asarray(vertices, dtype=np.float64)
        prob = np.asarray(contact_prob, dtype=np.float64)
        if vertices.ndim != 3 or vertices.shape[2] != 3:
            raise ValueError(f"vertices must have shape (T, V, 3), got {vertices.shape}")
        if prob.shape != vertices.shape[:2]:
            raise ValueError(f"contact_prob must have shape (T, V) = {vertices.shape[:2]}, got {prob.shape}")
        foot = np.zeros(vertices.shape[1], dtype=bool)
        foot[np.asarray(foot_vertex_ids, dtype=np.int64)] = True
        in_contact = prob > threshold
        return cls(frame_ids, [vertices[t][in_contact[t]] for t in range(len(vertices))],
                   [foot[in_contact[t]] for t in range(len(vertices))])


@dataclass(frozen=True)
class GroundTrack:
    """The ground plane of one track per frame: normal . x + offset = 0, normal unit and oriented up."""

    frame_ids: np.ndarray  # (T,)
    normal: np.ndarray  # (T, 3); NaN where not valid
    offset: np.ndarray  # (T,) metres; NaN where not valid
    observed: np.ndarray  # (T,) bool: the plane was seen under the feet in this frame
    valid: np.ndarray  # (T,) bool: observed or filled; all False when the feet never touched a plane


def estimate_ground_planes(tracks: Sequence[ContactTrack], *, up,
                           params: GroundParams | None = None) -> list[GroundTrack]:
    """Per-frame ground planes of every track; up (3,) is the up direction in the points' frame."""
    params = params or GroundParams()
    tracks = list(tracks)
    for i, track in enumerate(tracks):
        if not isinstance(track, ContactTrack):
            raise ValueError(f"tracks[{i}] must be a ContactTrack, got {type(track).__name__}")
    # Flattened for the core: every contact point with its track, its step in that track and its foot flag.
    # (The empty first entries keep np.concatenate's dtypes when there are no points at all.)
    chunks, foot = [np.empty((0, 3))], [np.empty(0, bool)]
    owner, step = [np.empty(0, np.int64)], [np.empty(0, np.int64)]
    for p, track in enumerate(tracks):
        for t, (points, is_foot) in enumerate(zip(track.points, track.is_foot)):
            chunks.append(points)
            owner.append(np.full(len(points), p, dtype=np.int64))
            step.append(np.full(len(points), t, dtype=np.int64))
            foot.append(is_foot)
    results = _core.track_planes(np.concatenate(chunks), np.concatenate(owner), np.concatenate(step),
                                 np.concatenate(foot), [t.frame_ids for t in tracks], up,
                                 params.core_options())
    return [GroundTrack(t.frame_ids.copy(), normal, offset, observed, valid)
            for t, (normal, offset, observed, valid) in zip(tracks, results)]
