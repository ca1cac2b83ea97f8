"""Post-hoc merging of track splits: one person's track broken into parts the online tracker could not join.

Two parts are one person's when they do not overlap in time, the second starts at most max_gap_s after the first
ends, their mean colour descriptors agree (Bhattacharyya distance at most max_appearance) and the person is where
it could be: the second part's first locations (median of its first `ends` camera-frame locations) lie within
  max_distance + max_speed * gap          across the line of sight, and
  depth_fraction * depth + max_speed * gap   along it (monocular depths are known to a fraction of themselves)
of the first part's last ones. Parts without a known location or descriptor are never merged. Among the pairs that
qualify, each part gets at most one successor and one predecessor, chosen by the Hungarian method
(scipy.optimize.linear_sum_assignment) on the sum of the normalised appearance and location distances; chains of
successors become one track that keeps its first part's id.

A short part that lies inside a gap of another track (the other track seen just before and just after it) is a
piece of that person when its colour agrees (the masks' colours, or, where those do not, the colours at the
keypoints within max_piece_colour: a piece is often a person coming out from behind another, whose patch's mask
covers both) and its bearing does: a piece (a crouching or half-detected person)
gets a depth from its box that is no guide, so its locations are moved along their lines of sight to the other
track's depths at the gap's two ends and compared across the line of sight only (max_distance + max_speed * time
from that end). It joins the track it fits best (cost: appearance plus the worse of the two ends).

Before either rule, frames are handed back where a tracked patch slid onto another person (hand_back_slides): a
person coming out from behind another is in that other's patch, and BlazePose there may pose the one coming out;
the track then follows them for a few frames and jumps back once their own track finds them again. A track whose
keypoints jump by slide_jump of the person's height or more from frame t-1 to t, just as another track comes back
at t (absent at t-1) nearer its keypoints at t-1 than its own at t are, had slid onto that person. Its frames up
to t-1 whose keypoints lie nearer the returning track's at t than its own at t (at most max_slide_frames of them,
contiguous, where the returning track has none) are the slide: those at most 1 / SLIDE_RATIO as far from the
returning pose as from its own are that person's and go to the returning track; the others, nearer but not
clearly, are a blend of the two people (BlazePose half on each) and are dropped from both.

A slide with no jump back (split_colour_changes): the track stays on the person it slid to, and its own person,
in full view, is found again as a new track within a second. The colours at the track's keypoints (torso and
thighs, appearance.pose_colour_descriptor; the mask's colours do not change while the patch holds both people)
change there for good: the colours of the colour_window frames before a frame s and of those from s (per-bin
medians) differ by min_colour_change or more (Bhattacharyya), and the new track's first colours lie nearer the
before-window's, by colour_margin or more, than the after-window's (s: the largest such change among the frames
up to max_reappear_s before the new track's first). The track is split where its frames around s go over
from the before-window's colours to the after-window's; the frames between, no nearer either by a factor of
TRANSITION_RATIO (a blend of the two people), are dropped, and the two parts are never merged again; the merge rule
then joins each part to whichever track agrees with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from m3c.perception.appearance import bhattacharyya_distance
from m3c.perception.types import pose_distance

INFEASIBLE = 1e6
SLIDE_CONFIDENCE = 0.3  # keypoints compared by the slide rule: those above this confidence (the tracker's)
TRANSITION_RATIO = 1.5  # a frame nearer neither window's colours than this factor is a blend, dropped by a split
SLIDE_RATIO = 2.0  # a slid frame nearer the returning pose than its own by less than this factor is a blend


@dataclass
class TrackMergeConfig:
    enabled: bool = True
    max_gap_s: float = 3.0         # seconds from the end of one part to the start of the next
    max_appearance: float = 0.3    # Bhattacharyya distance of the parts' mean colour descriptors
    max_distance: float = 0.75     # metres across the line of sight, plus max_speed per second of gap
    depth_fraction: float = 0.3    # along the line of sight, as a fraction of the depth, plus the same allowance
    max_speed: float = 3.0         # m/s a person may have moved during the gap
    ends: int = 10                 # locations at each part's end whose median is compared
    max_piece_s: float = 1.0       # longest part absorbed into another track's gap (a 0 turns the rule off)
    max_piece_colour: float = 0.5  # keypoint colours (Bhattacharyya) by which a piece fills a gap if the masks' don't
    max_slide_frames: int = 10     # most frames handed back from a track that slid onto another (0: off)
    slide_jump: float = 0.2        # the jump back that ends such a slide, in the person's height
    colour_window: int = 8         # frames each side of a colour change compared by split_colour_changes (0: off)
    min_colour_change: float = 0.5   # Bhattacharyya distance between the two windows' keypoint colours
    colour_margin: float = 0.2     # how much nearer the new track's colours lie to the before-window's
    max_reappear_s: float = 1.0    # the new track starts at most this long after the change

    def __post_init__(self):
        if min(self.max_gap_s, self.max_appearance, self.max_distance, self.depth_fraction, self.slide_jump,
               self.min_colour_change, self.colour_margin, self.max_reappear_s, self.max_piece_colour) <= 0:
            raise ValueError("max_gap_s, max_appearance, max_distance, depth_fraction, slide_jump, "
                             "min_colour_change, colour_margin, max_reappear_s and max_piece_colour must be > 0")
        if (self.max_speed < 0 or self.ends < 1 or self.max_piece_s < 0 or self.max_slide_frames < 0
                or self.colour_window < 0):
            raise ValueError("max_speed, max_piece_s, max_slide_frames and colour_window must be >= 0 and ends >= 1")


@dataclass
class TrackSegment:
    """What the merge rule sees of one track: its frames (n,) increasing, camera-frame locations (n, 3) in
    metres, the masks' colour descriptors (n, D) and the keypoints' (n, D) or None (rows of NaN where unknown)."""

    track_id: int
    frames: np.ndarray
    locations: np.ndarray
    appearances: np.ndarray
    pose_colours: np.ndarray | None = None

    def __post_init__(self):
        self.frames = np.asarray(self.frames, dtype=np.int64)
        self.locations = np.asarray(self.locations, dtype=np.float64).reshape(len(self.frames), 3)
        self.appearances = np.asarray(self.appearances, dtype=np.float64).reshape(len(self.frames), -1)
        if self.pose_colours is None:
            self.pose_colours = np.full((len(self.frames), 1), np.nan)
        self.pose_colours = np.asarray(self.pose_colours, dtype=np.float64).reshape(len(self.frames), -1)
        if len(self.frames) == 0 or np.any(np.diff(self.frames) <= 0):
            raise ValueError(f"track {self.track_id}: frames must be non-empty and increasing")

    def part(self, rows: slice) -> "TrackSegment":
        return TrackSegment(self.track_id, self.frames[rows], self.locations[rows], self.appearances[rows],
                            self.pose_colours[rows])

    def end_location(self, first: bool, count: int) -> np.ndarray | None:
        rows = self.locations[np.isfinite(self.locations).all(axis=1)]
        if len(rows) == 0:
            return None
        return np.median(rows[:count] if first else rows[-count:], axis=0)

    def mean_appearance(self, pose: bool = False) -> np.ndarray | None:
        """The mean of the known colour descriptors, renormalised: the masks' (or with pose, the keypoints')."""
        descriptors = self.pose_colours if pose else self.appearances
        rows = descriptors[np.isfinite(descriptors).all(axis=1)]
        if len(rows) == 0:
            return None
        mean = rows.mean(axis=0)
        return mean / mean.sum() if mean.sum() > 0 else None


def split_cost(before: TrackSegment, after: TrackSegment, fps: float, config: TrackMergeConfig) -> float | None:
    """The cost of joining `after` onto `before` (normalised appearance plus location distance, each <= 1 when
    the pair qualifies), or None when the two cannot be one person (see the module docstring)."""
    gap_s = (after.frames[0] - before.frames[-1]) / fps
    if gap_s <= 0 or gap_s > config.max_gap_s:
        return None
    a, b = before.mean_appearance(), after.mean_appearance()
    end, start = before.end_location(False, config.ends), after.end_location(True, config.ends)
    if a is None or b is None or end is None or start is None:
        return None
    appearance = bhattacharyya_distance(a, b) / config.max_appearance
    allowance = config.max_speed * gap_s
    across = np.linalg.norm(start[:2] - end[:2]) / (config.max_distance + allowance)
    along = abs(start[2] - end[2]) / (config.depth_fraction * abs(end[2]) + allowance)
    if appearance > 1.0 or across > 1.0 or along > 1.0:
        return None
    return float(appearance + max(across, along))


def piece_cost(host: TrackSegment, piece: TrackSegment, fps: float, config: TrackMergeConfig) -> float | None:
    """The cost of absorbing `piece` into a gap of `host` (normalised appearance plus the worse end's distance
    across the line of sight, each <= 1 when it qualifies), or None (see the module docstring)."""
    k = int(np.searchsorted(host.frames, piece.frames[0]))
    if not 0 < k < len(host.frames) or host.frames[k] <= piece.frames[-1]:
        return None  # not inside one gap of the host
    if (piece.frames[-1] - piece.frames[0] + 1) / fps > config.max_piece_s:
        return None
    if (host.frames[k] - host.frames[k - 1]) / fps > config.max_gap_s:
        return None
    a, b = host.mean_appearance(), piece.mean_appearance()
    before, after = host.part(slice(None, k)), host.part(slice(k, None))
    ends = [(before.end_location(False, config.ends), piece.end_location(True, config.ends),
             piece.frames[0] - host.frames[k - 1]),
            (after.end_location(True, config.ends), piece.end_location(False, config.ends),
             host.frames[k] - piece.frames[-1])]
    if a is None or b is None or any(h is None or p is None or h[2] <= 0 or p[2] <= 0 for h, p, _ in ends):
        return None
    appearance = bhattacharyya_distance(a, b) / config.max_appearance
    a_pose, b_pose = host.mean_appearance(pose=True), piece.mean_appearance(pose=True)
    if appearance > 1.0 and a_pose is not None and b_pose is not None:
        appearance = min(appearance, bhattacharyya_distance(a_pose, b_pose) / config.max_piece_colour)
    across = max(np.linalg.norm(p[:2] * (h[2] / p[2]) - h[:2]) / (config.max_distance + config.max_speed * n / fps)
                 for h, p, n in ends)
    if appearance > 1.0 or across > 1.0:
        return None
    return float(appearance + across)


def _joined(parts: list[TrackSegment]) -> TrackSegment:
    """One segment of parts that do not overlap in time (a chain of splits)."""
    order = np.argsort([p.frames[0] for p in parts])
    width = max(p.pose_colours.shape[1] for p in parts)  # parts without keypoint colours hold one NaN column
    pose_colours = [np.pad(parts[i].pose_colours, ((0, 0), (0, width - parts[i].pose_colours.shape[1])),
                           constant_values=np.nan) for i in order]
    return TrackSegment(parts[order[0]].track_id, np.concatenate([parts[i].frames for i in order]),
                        np.concatenate([parts[i].locations for i in order]),
                        np.concatenate([parts[i].appearances for i in order]), np.concatenate(pose_colours))


def absorb_pieces(segments: list[TrackSegment], fps: float, config: TrackMergeConfig) -> dict[int, int]:
    """piece id -> id of the track whose gap it fills (shortest pieces first; a part already absorbed hosts no
    other; pieces that overlap in time never fill the same host)."""
    hosted: dict[int, int] = {}
    filled: dict[int, set] = {}
    for piece in sorted(segments, key=lambda s: len(s.frames)):
        costs = [(c, host.track_id) for host in segments
                 if host is not piece and host.track_id not in hosted
                 and not filled.get(host.track_id, set()) & set(piece.frames.tolist())
                 and (c := piece_cost(host, piece, fps, config)) is not None]
        if costs:
            host_id = min(costs)[1]
            hosted[piece.track_id] = host_id
            filled.setdefault(host_id, set()).update(piece.frames.tolist())
    return hosted


def merge_track_splits(segments: list[TrackSegment], fps: float, config: TrackMergeConfig | None = None,
                       apart: set[frozenset] | None = None) -> dict[int, int]:
    """track id -> id of the track it joins (its chain's first part; itself when not merged) for every segment;
    the pairs of ids in `apart` (split_colour_changes's parts) are never joined to each other."""
    config = config or TrackMergeConfig()
    apart = apart or set()
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    ids = [s.track_id for s in segments]
    if len(set(ids)) != len(ids):
        raise ValueError(f"track ids must be unique, got {ids}")
    merged = {i: i for i in ids}
    if not config.enabled or len(segments) < 2:
        return merged
    cost = np.full((len(segments), len(segments)), INFEASIBLE)
    for i, before in enumerate(segments):
        for j, after in enumerate(segments):
            if i != j and frozenset((before.track_id, after.track_id)) not in apart:
                c = split_cost(before, after, fps, config)
                if c is not None:
                    cost[i, j] = c
    successor = {}
    for i, j in zip(*linear_sum_assignment(cost)):
        if cost[i, j] < INFEASIBLE:
            successor[int(i)] = int(j)
    has_predecessor = set(successor.values())
    for head in range(len(segments)):
        if head in has_predecessor:
            continue
        k = head
        while k in successor:
            k = successor[k]
            merged[ids[k]] = ids[head]
    if config.max_piece_s > 0:
        chains = [_joined([s for s in segments if merged[s.track_id] == head]) for head in sorted(set(merged.values()))]
        hosted = absorb_pieces(chains, fps, config)
        for i in ids:
            while merged[i] in hosted:
                merged[i] = hosted[merged[i]]
    return merged


def hand_back_slides(keypoints: dict[int, dict[int, np.ndarray]],
                     config: TrackMergeConfig | None = None) -> list[tuple[int, int, list[int], list[int]]]:
    """(from track, to track, frames handed on, blended frames dropped) of every slide found (see the module
    docstring), in the order found; the moves are made on keypoints as they are found, so a frame is handed on or
    dropped at most once. keypoints: track id -> frame -> (K >= 17, 3) image keypoints (u, v, confidence) of that
    track's person there."""
    config = config or TrackMergeConfig()
    if config.max_slide_frames == 0:
        return []
    tracks = {i: dict(frames) for i, frames in keypoints.items()}  # moved on as found; the caller's untouched

    def distance(a: np.ndarray, b: np.ndarray) -> float:
        return pose_distance(a, b, SLIDE_CONFIDENCE, SLIDE_CONFIDENCE)

    moves = []
    for a in sorted(tracks):
        for t in sorted(tracks[a]):
            if t - 1 not in tracks[a] or t not in tracks[a]:
                continue
            last, own = tracks[a][t - 1], tracks[a][t]
            jump = distance(last, own)  # inf where they share under 3 keypoints: no evidence of a jump
            if not config.slide_jump <= jump < np.inf:
                continue
            # The tracks that come back at t within slide_jump of a's keypoints at t-1 (nearer than a's own at t).
            returning = [(distance(last, tracks[b][t]), b) for b in sorted(tracks)
                         if b != a and t in tracks[b] and t - 1 not in tracks[b]]
            returning = [(d, b) for d, b in returning if d < config.slide_jump]
            if not returning:
                continue
            b = min(returning)[1]
            back, handed, blends = tracks[b][t], [], []
            s = t - 1
            while len(handed) + len(blends) < config.max_slide_frames and s in tracks[a] and s not in tracks[b]:
                to_back, to_own = distance(tracks[a][s], back), distance(tracks[a][s], own)
                if not to_back < to_own < np.inf:
                    break
                (handed if SLIDE_RATIO * to_back <= to_own else blends).append(s)
                s -= 1
            if handed + blends and len(handed) + len(blends) < len(tracks[a]):  # a track is never emptied
                for f in handed:
                    tracks[b][f] = tracks[a].pop(f)
                for f in blends:
                    del tracks[a][f]
                moves.append((a, b, sorted(handed), sorted(blends)))
    return moves


def _typical_colour(rows: list, least: int) -> np.ndarray | None:
    """The per-bin median of the known descriptors among rows, renormalised (a window's colours, unmoved by a few
    blended frames), or None with fewer than `least` known."""
    rows = [r for r in rows if r is not None]
    if len(rows) < max(1, least):
        return None
    median = np.median(rows, axis=0)
    return median / median.sum() if median.sum() > 0 else None


def split_colour_changes(colours: dict[int, dict[int, np.ndarray | None]], fps: float,
                         config: TrackMergeConfig | None = None) -> list[tuple[int, int, int, list[int]]]:
    """(track, new track whose start set it off, first frame of the part after the change, blended frames to
    drop) for every colour change found (see the module docstring), each track split at most once. colours:
    track id -> frame -> keypoint colour descriptor (appearance.pose_colour_descriptor) or None where unknown."""
    config = config or TrackMergeConfig()
    w = config.colour_window
    firsts = {i: min(frames) for i, frames in colours.items() if frames}
    if w == 0 or not firsts:
        return []
    lag = int(round(config.max_reappear_s * fps))
    start = min(firsts.values())
    splits, split = [], set()
    for new in sorted(firsts, key=lambda i: (firsts[i], i)):
        born = firsts[new]
        own = _typical_colour([colours[new][f] for f in sorted(colours[new])[:w]], w // 2)
        if born == start or own is None:
            continue  # there from the first frame (not a person found again), or its colours unknown
        best = None
        for k in sorted(colours):
            track = colours[k]
            if k == new or k in split or k not in firsts or firsts[k] >= born or max(track) < born:
                continue  # split already, or not seen across the new track's start
            for s in range(born - lag, born + 1):
                before = _typical_colour([track.get(f) for f in range(s - w, s)], w // 2)
                after = _typical_colour([track.get(f) for f in range(s, s + w)], w // 2)
                if before is None or after is None:
                    continue
                change = bhattacharyya_distance(before, after)
                nearer = bhattacharyya_distance(own, after) - bhattacharyya_distance(own, before)
                if (change >= config.min_colour_change and nearer >= config.colour_margin
                        and (best is None or change > best[0])):
                    best = (change, k, s, before, after)
        if best is None:
            continue
        _, k, s, before, after = best
        # Each frame around s: nearer one side's colours by TRANSITION_RATIO, or a blend of the two people. The
        # track is split at the first frame of the after side past the last of the before side, the blends
        # between them dropped.
        sides = {}
        for f in range(s - w, s + w):
            if colours[k].get(f) is not None:
                a, b = (bhattacharyya_distance(colours[k][f], ref) for ref in (before, after))
                sides[f] = "before" if TRANSITION_RATIO * a < b else "after" if TRANSITION_RATIO * b < a else "blend"
        last = max((f for f, side in sides.items() if side == "before"), default=s - w - 1)
        first = min((f for f, side in sides.items() if side == "after" and f > last), default=None)
        if first is None:
            continue
        dropped = [f for f in sorted(sides) if last < f < first]
        if any(f < first and f not in dropped for f in colours[k]):  # the part before is never empty
            splits.append((k, new, first, dropped))
            split.add(k)
    return splits
