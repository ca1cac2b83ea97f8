"""Multi-person tracking, SORT/DeepSORT-style with PHALP's cues (thesis 4.1.3, "Appearance-based Tracking").

Each track predicts its box with a constant-velocity Kalman filter (centre, width, height and their rates,
noise proportional to the box height as in DeepSORT). Detections are assigned by the Hungarian method
(scipy.optimize.linear_sum_assignment) on a cost that averages the available cues, each in [0, 1]:
  IoU        1 - IoU(predicted box, detection box)
  2D pose    1 - mean_k exp(-d_k^2 / (2 kappa^2)), d_k the distance of keypoint k once both poses are centred
             on the mean of the keypoints both see, over the box height (OKS-like; the pose's shape, as position
             is the other cues' part; box-centred keypoints jump whenever a partial mask moves the box)
  3D         1 - exp(-d^2 / 2), camera-frame person locations: d^2 = |dx, dy|^2 / sigma^2 + (dz / (r z))^2, the
             depth's uncertainty r z growing with the depth (a monocular depth is known to a fraction of itself)
  appearance Bhattacharyya distance of colour histograms inside the masks (track: running average); beyond
             max_appearance the pair is refused whatever the other cues say (a person stepping in front of
             another fits the hidden one's box, not its clothes)
Matching is a cascade: confirmed tracks seen in the previous frame first, then confirmed tracks lost for up to
max_age frames (re-identification after an occlusion or a detector miss), then tentative tracks; in the second
stage the stale IoU gives way to the distance from the predicted box
(1 - exp(-d^2 / (2 g^2)), g the gate) and the gate on the centre distance widens with the time lost.
A detection that the first stage gave to a track but whose pose and colours resemble a lost track's by
reclaim_margin more (and that the lost track re-identifies) goes to the lost track instead: a person coming
out from behind another is often detected in a box spanning both, which the front person's track takes on the
boxes' overlap although the pose in it is the other person's.
Unmatched detections start tentative tracks, confirmed after min_hits detections; a tentative track that
misses a frame is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from m3c.perception.appearance import bhattacharyya_distance
from m3c.perception.boxes import as_box, iou_matrix

INFEASIBLE = 1e6


@dataclass
class TrackerConfig:
    iou_weight: float = 1.0
    pose_weight: float = 1.0
    location_weight: float = 1.0
    appearance_weight: float = 1.0
    reid_motion_weight: float = 0.5  # re-identification: distance from the predicted box, instead of IoU
    max_cost: float = 0.6        # a detection joins a track seen in the previous frame below this cost
    reid_max_cost: float = 0.45  # ... or a lost track below this one
    reclaim_margin: float = 0.15  # a lost track whose pose and colours fit a detection this much better than
    #                               those of the track seen in the previous frame that took it gets it
    max_age: int = 30            # frames a lost track waits to be re-identified
    min_hits: int = 3            # detections before a track counts (tentative until then)
    gate: float = 1.0            # centre distance gate, in box heights; widens by 0.5 per frame lost
    pose_kappa: float = 0.1      # keypoint distance scale, fraction of the box height
    min_keypoint_confidence: float = 0.3
    location_sigma: float = 0.5  # metres, across the line of sight
    depth_sigma: float = 0.2     # along it, as a fraction of the depth
    appearance_momentum: float = 0.8  # weight of the old descriptor in the running average
    max_appearance: float = 0.6  # colour distance beyond which a detection is never a track's (a gate)
    history: int = 5             # recent poses and locations a track keeps (pose: the closest; location: median)

    def __post_init__(self):
        weights = (self.iou_weight, self.pose_weight, self.location_weight, self.appearance_weight,
                   self.reid_motion_weight)
        if min(weights) < 0 or sum(weights) <= 0:
            raise ValueError("cue weights must be >= 0 with at least one > 0")
        if self.max_age < 1 or self.min_hits < 1 or self.history < 1:
            raise ValueError("max_age, min_hits and history must be >= 1")
        if min(self.location_sigma, self.depth_sigma, self.pose_kappa) <= 0:
            raise ValueError("location_sigma, depth_sigma and pose_kappa must be > 0")
        if not 0 < self.max_appearance <= 1:
            raise ValueError(f"max_appearance must be in (0, 1] (1: no colour gate), got {self.max_appearance}")
        if self.reclaim_margin < 0:
            raise ValueError(f"reclaim_margin must be >= 0 (a value above 1 turns reclaiming off), got "
                             f"{self.reclaim_margin}")
        if not 0 <= self.appearance_momentum < 1:
            raise ValueError("appearance_momentum must be in [0, 1)")


@dataclass
class Observation:
    """What the tracker sees of one detection: box (4,) pixels; optional keypoints (K, 3), camera-frame location
    (3,) metres and appearance descriptor (D,)."""

    box: np.ndarray
    keypoints: np.ndarray | None = None
    location: np.ndarray | None = None
    appearance: np.ndarray | None = None

    def __post_init__(self):
        self.box = as_box(self.box)


class BoxKalmanFilter:
    """Constant-velocity Kalman filter on (cx, cy, w, h); noise standard deviations scale with the height."""

    POSITION_STD = 1.0 / 20.0
    VELOCITY_STD = 1.0 / 160.0

    def __init__(self, box: np.ndarray):
        cx, cy, w, h = _box_to_cxcywh(box)
        self.mean = np.array([cx, cy, w, h, 0, 0, 0, 0], dtype=np.float64)
        s = np.array([2 * self.POSITION_STD * h] * 4 + [10 * self.VELOCITY_STD * h] * 4)
        self.cov = np.diag(s ** 2)
        self._F = np.eye(8)
        self._F[:4, 4:] = np.eye(4)
        self._H = np.eye(4, 8)

    def predict(self) -> None:
        h = max(self.mean[3], 1.0)
        q = np.array([self.POSITION_STD * h] * 4 + [self.VELOCITY_STD * h] * 4) ** 2
        self.mean = self._F @ self.mean
        self.mean[2:4] = np.maximum(self.mean[2:4], 1.0)
        self.cov = self._F @ self.cov @ self._F.T + np.diag(q)

    def update(self, box: np.ndarray) -> None:
        z = np.array(_box_to_cxcywh(box))
        h = max(self.mean[3], 1.0)
        R = np.diag(np.full(4, (self.POSITION_STD * h) ** 2))
        S = self._H @ self.cov @ self._H.T + R
        gain = np.linalg.solve(S, self._H @ self.cov).T
        self.mean = self.mean + gain @ (z - self._H @ self.mean)
        self.cov = (np.eye(8) - gain @ self._H) @ self.cov

    def copy(self) -> "BoxKalmanFilter":
        other = BoxKalmanFilter.__new__(BoxKalmanFilter)
        other.mean, other.cov, other._F, other._H = self.mean.copy(), self.cov.copy(), self._F, self._H
        return other

    @property
    def box(self) -> np.ndarray:
        cx, cy, w, h = self.mean[:4]
        return np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])


def _normalise_keypoints(keypoints, box) -> np.ndarray:
    """(K, 3) keypoints as (u - cx) / h, (v - cy) / h, confidence for the box's centre and height."""
    cx, cy, _, h = _box_to_cxcywh(box)
    k = np.asarray(keypoints, dtype=np.float64).copy()
    k[:, 0] = (k[:, 0] - cx) / h
    k[:, 1] = (k[:, 1] - cy) / h
    return k


def _recent(items: list, count: int) -> list:
    return items[len(items) - count:] if count > 0 else []


def _box_to_cxcywh(box) -> tuple[float, float, float, float]:
    b = as_box(box)
    return 0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3]), max(b[2] - b[0], 1.0), max(b[3] - b[1], 1.0)


@dataclass
class _Track:
    track_id: int
    kalman: BoxKalmanFilter
    poses: list = field(default_factory=list)  # the last `history` (K, 3) keypoints: (u - cx) / h, (v - cy) / h, c
    locations: list = field(default_factory=list)  # the last `history` locations (3,)
    location: np.ndarray | None = None  # their median: one wild monocular depth does not move it
    location_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    appearance: np.ndarray | None = None
    hits: int = 1
    time_since_update: int = 0

    def predicted_location(self) -> np.ndarray | None:
        if self.location is None:
            return None
        return self.location + self.time_since_update * self.location_velocity


class Tracker:
    """Online tracker: call update() once per frame with that frame's observations; it returns a track id per
    observation. A track counts once it has min_hits detections (see confirmed_ids())."""

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._hits: dict[int, int] = {}

    # Costs ------------------------------------------------------------------------------------------------
    def _pose_cost(self, track: _Track, obs: Observation) -> float | None:
        """OKS-like dissimilarity of the two poses in box-normalised coordinates (keypoints relative to the box
        centre, over its height): the pose's shape, while the boxes, locations and gates cover where it is."""
        if not track.poses or obs.keypoints is None:
            return None
        c = self.config.min_keypoint_confidence
        observed = _normalise_keypoints(obs.keypoints, obs.box)
        costs = []
        for pose in track.poses:  # the closest of the recent poses: a detector's one wild pose is forgotten
            k = min(len(observed), len(pose))
            ours, theirs = pose[:k], observed[:k]
            both = (ours[:, 2] >= c) & (theirs[:, 2] >= c)
            if both.sum() < 4:
                continue
            ours, theirs = ours[both, :2], theirs[both, :2]
            offset = (ours - ours.mean(axis=0)) - (theirs - theirs.mean(axis=0))
            d2 = np.sum(offset ** 2, axis=1) / self.config.pose_kappa ** 2
            costs.append(1.0 - np.mean(np.exp(-0.5 * d2)))
        return float(min(costs)) if costs else None

    def _location_cost(self, track: _Track, obs: Observation) -> float | None:
        predicted = track.predicted_location()
        if predicted is None or obs.location is None:
            return None
        cfg = self.config
        d = np.asarray(obs.location, dtype=np.float64) - predicted
        depth_sigma = cfg.depth_sigma * max(abs(float(predicted[2])), 1e-3)
        d2 = float(d[0] ** 2 + d[1] ** 2) / cfg.location_sigma ** 2 + float(d[2] / depth_sigma) ** 2
        return float(1.0 - np.exp(-0.5 * d2))

    def _cost_matrix(self, tracks: list[_Track], observations: list[Observation], use_iou: bool) -> np.ndarray:
        cfg = self.config
        cost = np.full((len(tracks), len(observations)), INFEASIBLE)
        if not tracks or not observations:
            return cost
        predicted = np.array([t.kalman.box for t in tracks])
        ious = iou_matrix(predicted, np.array([o.box for o in observations]))
        for i, track in enumerate(tracks):
            pb = predicted[i]
            height = max(pb[3] - pb[1], 1.0)
            gate = cfg.gate * height * (1.0 + 0.5 * max(track.time_since_update - 1, 0))
            centre = 0.5 * (pb[:2] + pb[2:])
            for j, obs in enumerate(observations):
                if np.linalg.norm(0.5 * (obs.box[:2] + obs.box[2:]) - centre) > gate and ious[i, j] == 0:
                    continue
                terms = []
                if use_iou and cfg.iou_weight > 0:
                    terms.append((cfg.iou_weight, 1.0 - ious[i, j]))
                elif not use_iou and cfg.reid_motion_weight > 0:
                    # Where the prediction says the person went, at the gate's (growing) scale.
                    d2 = float(np.sum((0.5 * (obs.box[:2] + obs.box[2:]) - centre) ** 2))
                    terms.append((cfg.reid_motion_weight, 1.0 - np.exp(-0.5 * d2 / gate ** 2)))
                pose = self._pose_cost(track, obs) if cfg.pose_weight > 0 else None
                if pose is not None:
                    terms.append((cfg.pose_weight, pose))
                location = self._location_cost(track, obs) if cfg.location_weight > 0 else None
                if location is not None:
                    terms.append((cfg.location_weight, location))
                if cfg.appearance_weight > 0 and track.appearance is not None and obs.appearance is not None:
                    distance = bhattacharyya_distance(track.appearance, obs.appearance)
                    if distance > cfg.max_appearance:
                        continue  # other clothes: another person, however well the box fits
                    terms.append((cfg.appearance_weight, distance))
                if terms:
                    w = np.array([t[0] for t in terms])
                    cost[i, j] = float(np.dot(w, [t[1] for t in terms]) / w.sum())
        return cost

    @staticmethod
    def _assign(cost: np.ndarray, max_cost: float) -> list[tuple[int, int]]:
        if cost.size == 0:
            return []
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] < max_cost]

    # Updates ----------------------------------------------------------------------------------------------
    def _absorb(self, track: _Track, obs: Observation) -> None:
        track.kalman.update(obs.box)
        history = self.config.history
        if obs.keypoints is not None:
            track.poses = _recent(track.poses, history - 1) + [_normalise_keypoints(obs.keypoints, obs.box)]
        if obs.location is not None:
            track.locations = _recent(track.locations, history - 1) + [np.asarray(obs.location, dtype=np.float64)]
            location = np.median(track.locations, axis=0)
            if track.location is not None:
                gap = max(track.time_since_update, 1)
                track.location_velocity = 0.5 * track.location_velocity + 0.5 * (location - track.location) / gap
            track.location = location
        if obs.appearance is not None:
            m = self.config.appearance_momentum
            old = track.appearance
            track.appearance = obs.appearance if old is None else m * old + (1 - m) * obs.appearance
        track.hits += 1
        track.time_since_update = 0
        self._hits[track.track_id] = track.hits

    def _match(self, tracks: list[_Track], observations: list[Observation], ids: list[int], use_iou: bool,
               max_cost: float) -> None:
        """One cascade stage: assigns the observations without an id yet (ids[c] < 0) to `tracks`."""
        free = [c for c in range(len(observations)) if ids[c] < 0]
        remaining = [observations[c] for c in free]
        for r, c in self._assign(self._cost_matrix(tracks, remaining, use_iou), max_cost):
            self._absorb(tracks[r], remaining[c])
            ids[free[c]] = tracks[r].track_id

    def _looks(self, track: _Track, obs: Observation) -> float | None:
        """Mean of the cues that tell people apart wherever they stand (pose, colours): those known."""
        cues = [self._pose_cost(track, obs)]
        if track.appearance is not None and obs.appearance is not None:
            cues.append(bhattacharyya_distance(track.appearance, obs.appearance))
        cues = [c for c in cues if c is not None]
        return float(np.mean(cues)) if cues else None

    def _reclaimed(self, pairs: list[tuple[int, int]], seen: list[_Track], lost: list[_Track],
                   observations: list[Observation]) -> dict[int, int]:
        """{observation: stage-1 track row} of the stage-1 pairs whose detection a lost track re-identifies (cost
        below reid_max_cost) and resembles (pose, colours) by reclaim_margin more than the track that took it:
        a person back from behind another, detected in a box spanning both that the other's track took on the
        overlap of the boxes."""
        cfg = self.config
        if not lost or not pairs:
            return {}
        reid = self._cost_matrix(lost, observations, False)
        out = {}
        for r, c in pairs:
            best = int(np.argmin(reid[:, c]))
            if reid[best, c] >= cfg.reid_max_cost:
                continue
            theirs, ours = self._looks(lost[best], observations[c]), self._looks(seen[r], observations[c])
            if theirs is not None and ours is not None and ours - theirs >= cfg.reclaim_margin:
                out[c] = r
        return out

    def update(self, observations: list[Observation]) -> list[int]:
        cfg = self.config
        for track in self._tracks:
            track.kalman.predict()
            track.time_since_update += 1
        ids = [-1] * len(observations)
        confirmed = [t for t in self._tracks if t.hits >= cfg.min_hits]
        seen = [t for t in confirmed if t.time_since_update == 1]
        lost = [t for t in confirmed if t.time_since_update > 1]
        # Stage 1: confirmed tracks seen in the previous frame, all cues. Stage 2: confirmed tracks lost for a
        # while (re-identification), without the stale IoU. Stage 3: tentative tracks, last, so a track started
        # on a partial view of a known person cannot take that person's next detection from its own track.
        pairs = self._assign(self._cost_matrix(seen, observations, True), cfg.max_cost)
        reclaimed = self._reclaimed(pairs, seen, lost, observations)
        for r, c in pairs:
            if c not in reclaimed:
                self._absorb(seen[r], observations[c])
                ids[c] = seen[r].track_id
        self._match(lost, observations, ids, False, cfg.reid_max_cost)
        for c, r in reclaimed.items():  # no lost track took it after all: it stays with the first taker
            if ids[c] < 0:
                self._absorb(seen[r], observations[c])
                ids[c] = seen[r].track_id
        self._match([t for t in self._tracks if t.hits < cfg.min_hits], observations, ids, True, cfg.max_cost)
        free = [c for c in range(len(observations)) if ids[c] < 0]
        # Drop tentative tracks that missed and tracks lost for too long; start new ones.
        self._tracks = [t for t in self._tracks if t.time_since_update == 0 or
                        (t.hits >= cfg.min_hits and t.time_since_update <= cfg.max_age)]
        for c in free:
            obs = observations[c]
            track = _Track(self._next_id, BoxKalmanFilter(obs.box))
            track.hits = 0
            track.time_since_update = 1
            self._absorb(track, obs)
            self._tracks.append(track)
            ids[c] = track.track_id
            self._next_id += 1
        return ids

    def predicted_boxes(self, max_lost: int = 5) -> list[tuple[int, np.ndarray]]:
        """(track id, box) of the live tracks (tentative ones included) that missed fewer than max_lost frames,
        predicted one frame ahead: where to look for each person in the next frame."""
        out = []
        for t in self._tracks:
            if t.time_since_update < max_lost:
                kalman = t.kalman.copy()
                kalman.predict()
                out.append((t.track_id, kalman.box))
        return out

    def confirmed_ids(self) -> set[int]:
        """Ids of every track that reached min_hits detections so far."""
        return {i for i, hits in self._hits.items() if hits >= self.config.min_hits}
