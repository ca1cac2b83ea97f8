"""The perception stage end to end: video -> tracked people with keypoints, masks, camera-local bodies, contacts.

Per frame (thesis 4.1.1-4.1.2): detector -> (+ the tracker's predicted boxes for people the detector missed)
-> segmenter -> 2D pose on isolated patches -> tracker (boxes, pose, rough 3D location, colour histograms).
Per track (4.1.3): the body fit (warm-started frame to frame), kinematic contacts, gender.
Which estimator runs each task is named in PerceptionConfig and recorded in the result.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import cv2
import numpy as np

from m3c.body.joint_names import CONTACT_JOINTS
from m3c.io import atomic_path, save_npz_atomic
from m3c.io.video import default_intrinsics, iter_frames, probe_video
from m3c.perception.appearance import appearance_descriptor, pose_colour_descriptor
from m3c.perception.body import RESTART_GAP, BodyFitConfig, BodyFits, cold_starts, rough_location
from m3c.perception.contacts import contact_rest_heights, estimate_up, steady_depth
from m3c.perception.ground_motion import GroundMotionConfig, contact_pixels, ground_flow, ground_speeds
from m3c.perception.boxes import clip_boxes
from m3c.perception.interfaces import TASKS
from m3c.perception.paf import skeleton_box, skeleton_mask, skeletons_for_lost_tracks
from m3c.perception.registry import create
from m3c.perception.track_merge import (TrackMergeConfig, TrackSegment, hand_back_slides, merge_track_splits,
                                        split_colour_changes)
from m3c.perception.tracking import Observation, Tracker, TrackerConfig
from m3c.perception.types import FrameContext, Person, pack_mask, pose_distance
from m3c.pipeline.finite import index_ranges

LOG = logging.getLogger("m3c.perception.pipeline")

DEFAULT_ESTIMATORS = {"detector": "mediapipe", "segmenter": "mediapipe", "pose2d": "mediapipe", "body": "fit",
                      "contacts": "kinematic", "depth": "none", "gender": "neutral"}
MASK_DOWNSAMPLE = 4


@dataclass
class EstimatorSpec:
    name: str
    options: dict = field(default_factory=dict)


@dataclass
class PerceptionConfig:
    """estimators: task -> EstimatorSpec (defaults DEFAULT_ESTIMATORS). intrinsics: fx, fy, cx, cy or None for
    default_intrinsics().
    detect_every: the detector searches for new people every this many frames (and in any frame where a
    tracked person was not found again); in between, people are found on the patches of their tracks'
    predicted boxes, enlarged by proposal_margin of their height on each side.
    restart_gap: a track's body fit starts cold after more than this many frames without it.
    merge: how track splits are merged after tracking, and frames of a track that slid onto another person handed
        back (m3c.perception.track_merge).
    ground_motion: how the feet's motion against the ground is read from the images for the contacts
    (m3c.perception.ground_motion; enabled false: the feet's heights and their motion relative to the body).
    contact_depth_window: the contacts read each track's fit with its depth steadied (m3c.perception.contacts.
    steady_depth: the root's median depth within +- this many seconds; None: the fit as it is).
    duplicate_iou: two people whose boxes overlap more than this are one (the higher score stays).
    padding: pixels around a tight box before it is squared (m3c.perception.boxes; the thesis's 5): the patches of
    every estimator that takes a padding (unless its own options set one) and the square boxes handed over."""

    estimators: dict = field(default_factory=lambda: {t: EstimatorSpec(n) for t, n in DEFAULT_ESTIMATORS.items()})
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    merge: TrackMergeConfig = field(default_factory=TrackMergeConfig)
    ground_motion: GroundMotionConfig = field(default_factory=GroundMotionConfig)
    intrinsics: tuple | None = None
    detect_every: int = 5
    proposal_margin: float = 0.1
    restart_gap: int = RESTART_GAP
    duplicate_iou: float = 0.6
    save_masks: bool = True
    padding: float = 5.0
    # A standing man 10 m from the basketball clip's camera: his fit's depth spans 8.9-11.2 m (5-95%), his feet
    # move 1.5 m/s median, and a foot of his is planted in 43% of frames; with the depth steadied over +- 1 s, 83%.
    contact_depth_window: float | None = 1.0
    # A tracked person BlazePose finds nobody on, while the detector's multi-person network sees someone within
    # this many of their height of their last pose whom nobody found claims, is kept on that skeleton (0: off).
    # Opt-in (0.25): it raised recall on the video benchmark (seed 5's pan 90.5 -> 93.4%) but the 2D-only fits
    # of those frames made the basketball clip's player faster (0.68 -> 0.88 m/s) and her slower foot slide more.
    skeleton_agreement: float = 0.0

    def __post_init__(self):
        if self.contact_depth_window is not None and not self.contact_depth_window > 0:
            raise ValueError(f"contact_depth_window must be > 0 seconds or None, got {self.contact_depth_window}")
        if not (np.isfinite(self.skeleton_agreement) and self.skeleton_agreement >= 0):
            raise ValueError(f"skeleton_agreement must be >= 0 (0: off), got {self.skeleton_agreement}")
        if self.detect_every < 1:
            raise ValueError(f"detect_every must be >= 1, got {self.detect_every}")
        if not (np.isfinite(self.padding) and self.padding >= 0):
            raise ValueError(f"padding must be a finite number of pixels >= 0, got {self.padding}")
        missing = sorted(set(TASKS) - set(self.estimators))
        if missing:
            raise ValueError(f"no estimator named for: {', '.join(missing)}")

    @classmethod
    def from_dict(cls, data: dict) -> "PerceptionConfig":
        """{"detector": "hog" | {"name": "hog", "options": {...}}, ..., "tracker": {...}, "intrinsics": [...],
        "detect_every": 5, ...}; tasks not named keep their defaults."""
        data = dict(data or {})
        if "static_camera" in data:
            raise ValueError("static_camera is no longer a perception setting (the contacts use one rule in any "
                             "camera); drop it, and declare a still camera to the vo node instead (m3c run "
                             "--static-camera, or vo.static: true)")
        estimators = {t: EstimatorSpec(n) for t, n in DEFAULT_ESTIMATORS.items()}
        for task in TASKS:
            if task not in data:
                continue
            spec = data.pop(task)
            if isinstance(spec, str):
                estimators[task] = EstimatorSpec(spec)
            elif isinstance(spec, dict) and "name" in spec and set(spec) <= {"name", "options"}:
                estimators[task] = EstimatorSpec(str(spec["name"]), dict(spec.get("options") or {}))
            else:
                raise ValueError(f"{task}: give an estimator name or {{name: ..., options: {{...}}}}, got {spec!r}")
        tracker = TrackerConfig(**(data.pop("tracker", None) or {}))
        merge = TrackMergeConfig(**(data.pop("merge", None) or {}))
        ground_motion = GroundMotionConfig(**(data.pop("ground_motion", None) or {}))
        known = {f.name for f in fields(cls)} - {"estimators", "tracker", "merge", "ground_motion"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown perception setting(s): {', '.join(unknown)}; known: tasks {', '.join(TASKS)}, "
                             f"tracker, merge, ground_motion, {', '.join(sorted(known))}")
        return cls(estimators=estimators, tracker=tracker, merge=merge, ground_motion=ground_motion, **data)

    @classmethod
    def from_yaml(cls, path: str | Path) -> "PerceptionConfig":
        import yaml

        with open(path) as fh:
            return cls.from_dict(yaml.safe_load(fh) or {})

    def to_dict(self) -> dict:
        out = {task: {"name": spec.name, "options": dict(spec.options)} for task, spec in self.estimators.items()}
        out["tracker"] = asdict(self.tracker)
        out["merge"] = asdict(self.merge)
        out["ground_motion"] = {k: list(v) if isinstance(v, tuple) else v
                                for k, v in asdict(self.ground_motion).items()}
        for f in fields(self):
            if f.name not in ("estimators", "tracker", "merge", "ground_motion"):
                value = getattr(self, f.name)
                out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


@dataclass
class PersonTrack:
    """One tracked person over the frames it was seen in (n of them, increasing frame_ids).

    boxes (n, 4), scores (n,), keypoints (n, K, 3) u, v, confidence with K = 17 (COCO-17) or 21 (COCO-17 then
    types.FOOT_KEYPOINT_NAMES), keypoints3d (n, K, 4) metric root-relative x, y, z and confidence (confidence 0
    where the pose estimator gave none), bodies: the
    camera-local fits, contacts (n, 4) for m3c.body.joint_names.CONTACT_JOINTS (feet planted: still against the
    ground), gender, estimators: task -> name; ground_contacts (n, 4) or None: feet on the ground by the heights
    rule alone, for the ground fit, kept when the contacts also read the images (ground_motion), whose looser
    height limit would let the ground's points spread upwards.
    """

    track_id: int
    frame_ids: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray
    keypoints: np.ndarray
    keypoints3d: np.ndarray
    bodies: BodyFits
    contacts: np.ndarray
    gender: str
    estimators: dict
    # per frame ((bits, h, w) of types.pack_mask, mask_box) or None; kept in memory only (not saved)
    masks: list | None = None
    ground_contacts: np.ndarray | None = None


@dataclass
class PerceptionResult:
    video: str
    fps: float
    image_size: tuple  # (height, width)
    intrinsics: np.ndarray
    num_frames: int
    tracks: list
    estimators: dict
    seconds: dict  # stage -> seconds
    frame_masks: np.ndarray | None = None  # (T, H/4, ceil(W/4 / 8)) packed bits: any person's mask, 4x downsampled
    people_per_frame: np.ndarray | None = None  # (T,) people found per frame (before track filtering)
    depth: np.ndarray | None = None  # (T, H/4, W/4) float32 relative depth, 4x downsampled; None without estimator
    merged: dict | None = None  # track id -> the id of the track it was merged into (splits of one person)

    def save(self, path: str | Path) -> None:
        """OUT.npz (arrays, track k's under "track{k}/...") and OUT.json (a readable summary), both atomic."""
        path = Path(path)
        arrays = {"fps": np.float64(self.fps), "image_size": np.array(self.image_size), "intrinsics": self.intrinsics,
                  "num_frames": np.int64(self.num_frames)}
        if self.frame_masks is not None:
            arrays["frame_masks"] = self.frame_masks
        if self.people_per_frame is not None:
            arrays["people_per_frame"] = self.people_per_frame
        if self.depth is not None:
            arrays["depth"] = self.depth
        for k, t in enumerate(self.tracks):
            p = f"track{k}/"
            b = t.bodies
            arrays.update({p + "track_id": np.int64(t.track_id), p + "frame_ids": t.frame_ids, p + "boxes": t.boxes,
                           p + "scores": t.scores, p + "keypoints": t.keypoints.astype(np.float32),
                           p + "keypoints3d": t.keypoints3d.astype(np.float32),
                           p + "transl": b.transl.astype(np.float32),
                           p + "root_orient": b.root_orient.astype(np.float32),
                           p + "body_pose": b.body_pose.astype(np.float32), p + "betas": b.betas.astype(np.float32),
                           p + "reprojection_error_px": b.reprojection_error_px.astype(np.float32),
                           p + "keypoint_error_px": b.keypoint_error_px.astype(np.float32),
                           p + "num_keypoints": b.num_keypoints, p + "warm_started": b.warm_started,
                           p + "fit_status": np.array(b.status), p + "contacts": t.contacts.astype(np.float32),
                           p + "gender": np.array(t.gender)})
            if t.ground_contacts is not None:
                arrays[p + "ground_contacts"] = t.ground_contacts.astype(np.float32)
        save_npz_atomic(path.with_suffix(".npz"), **arrays)
        with atomic_path(path.with_suffix(".json")) as tmp:
            tmp.write_text(json.dumps(self.summary(), indent=2))

    def summary(self) -> dict:
        tracks = []
        for t in self.tracks:
            valid = t.bodies.valid
            errors = t.bodies.reprojection_error_px[valid]
            tracks.append({"track_id": int(t.track_id), "first_frame": int(t.frame_ids[0]),
                           "last_frame": int(t.frame_ids[-1]), "frames": int(len(t.frame_ids)),
                           "fitted_frames": int(valid.sum()), "gender": t.gender,
                           "median_reprojection_error_px": float(np.median(errors)) if len(errors) else None,
                           "estimators": t.estimators})
        return {"video": self.video, "fps": self.fps, "image_size": list(self.image_size),
                "intrinsics": [float(v) for v in self.intrinsics], "num_frames": int(self.num_frames),
                "estimators": self.estimators, "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
                "merged": {str(k): int(v) for k, v in (self.merged or {}).items()}, "tracks": tracks}


def _same_person(a: np.ndarray, b: np.ndarray, max_iou: float) -> bool:
    """Boxes overlapping by more than max_iou, or one lying (80%) inside the other, hold one person."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return False
    inter = w * h
    area_a, area_b = (a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1])
    return inter > max_iou * (area_a + area_b - inter) or inter >= 0.8 * min(area_a, area_b)


def _dedupe(people: list[Person], max_iou: float, min_pose_distance: float = 0.15) -> list[Person]:
    """The people less their duplicates (the higher score stays): overlapping boxes (_same_person) hold one person
    unless both people's keypoints are apart by more than min_pose_distance of the height (pose_distance): one
    person standing partly behind another."""
    kept: list[Person] = []

    def apart(a: Person, b: Person) -> bool:
        return (a.keypoints is not None and b.keypoints is not None
                and pose_distance(a.keypoints, b.keypoints, 0.49, 0.49) > min_pose_distance
                and pose_distance(b.keypoints, a.keypoints, 0.49, 0.49) > min_pose_distance)

    for person in sorted(people, key=lambda p: -p.score):
        if not any(_same_person(person.box, k.box, max_iou) and not apart(person, k) for k in kept):
            kept.append(person)
    return kept


def _proposal(box: np.ndarray, margin: float, size: tuple[int, int]) -> Person | None:
    grow = margin * (box[3] - box[1])
    b = clip_boxes(box + np.array([-grow, -grow, grow, grow]), size)
    if b[2] - b[0] < 8 or b[3] - b[1] < 8:
        return None
    return Person(b, 0.0, sources={"detector": "tracker"})


def _people_mask(people: list[Person], size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: True where any person's mask is."""
    mask = np.zeros(size, dtype=bool)
    for p in people:
        if p.mask is not None:
            mask |= p.full_mask(size)
    return mask


def _pack_frame_mask(mask: np.ndarray) -> np.ndarray:
    small = mask[MASK_DOWNSAMPLE // 2::MASK_DOWNSAMPLE, MASK_DOWNSAMPLE // 2::MASK_DOWNSAMPLE]
    return np.packbits(small, axis=1)


def run_perception(video: str | Path, config: PerceptionConfig | None = None, max_frames: int | None = None,
                   progress: Callable[[int], None] | None = None) -> PerceptionResult:
    """Runs every perception estimator of `config` over a video file (its frame rate read from the file)."""
    info = probe_video(video)
    frames = (image for _, image in iter_frames(video, stop=max_frames, colour="rgb"))
    return run_perception_frames(frames, info.fps, (info.height, info.width), config, progress, str(video))


def run_perception_frames(frames: Iterable[np.ndarray], fps: float, image_size: tuple[int, int],
                          config: PerceptionConfig | None = None, progress: Callable[[int], None] | None = None,
                          source: str = "frames") -> PerceptionResult:
    """Runs every perception estimator of `config` over RGB frames (H, W, 3) uint8 of size image_size
    (height, width) at fps frames per second."""
    config = config or PerceptionConfig()
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    height, width = (int(v) for v in image_size)
    intrinsics = (np.asarray(config.intrinsics, dtype=np.float64) if config.intrinsics is not None
                  else default_intrinsics(width, height))
    if intrinsics.shape != (4,) or not np.isfinite(intrinsics).all() or (intrinsics[:2] <= 0).any():
        raise ValueError(f"intrinsics must be fx, fy, cx, cy with positive focal lengths, got {config.intrinsics}")
    shared: dict = {}
    est = {task: create(task, spec.name, spec.options, shared, defaults={"padding": config.padding})
           for task, spec in config.estimators.items()}
    names = {task: e.name for task, e in est.items()}
    tracker = Tracker(config.tracker)
    seconds = {"tracked_patches": 0.0, "detect": 0.0, "new_patches": 0.0, "depth": 0.0, "track": 0.0, "body": 0.0,
               "contacts": 0.0, "ground_motion": 0.0}
    records: dict[int, list[tuple[int, Person]]] = {}
    # Per record: location, mask colours, keypoint colours (None where unknown).
    cues: dict[int, list[tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]]] = {}
    # The ground's image motion near each person's contact points, from a frame to the next: track -> frame -> (4, 2)
    flows: dict[int, dict[int, np.ndarray]] = {}
    motion = config.ground_motion
    previous = None  # (gray frame, people mask, [(track id, contact pixels (4, 2), box height)]) of the last frame
    frame_masks, people_per_frame, depth_maps = [], [], []
    on_skeletons: dict[int, list[int]] = {}  # track -> frames it was kept on the network's skeleton
    num_frames = 0
    try:
        for index, image in enumerate(frames):
            ctx = FrameContext(image, index)
            if ctx.size != (height, width):
                raise ValueError(f"frame {index} is {ctx.size[0]} x {ctx.size[1]}, expected {height} x {width}")
            t0 = time.perf_counter()
            # People where their tracks predict them: found on their own (isolated) patches.
            predicted = [(i, p) for i, p in ((i, _proposal(box, config.proposal_margin, ctx.size))
                                             for i, box in tracker.predicted_boxes()) if p is not None]
            proposals = [p for _, p in predicted]
            posed = _posed_each(est, ctx, proposals) if proposals else []
            tracked = [p for p in posed if p is not None]
            lost = [i for (i, _), p in zip(predicted, posed) if p is None]
            t1 = time.perf_counter()
            # New people (and tracked ones the patches missed).
            new: list[Person] = []
            if index % config.detect_every == 0 or len(tracked) < len(proposals):
                new = est["detector"].detect(ctx, known=tracked)
            t2 = time.perf_counter()
            if new:
                # Posed together, so every patch is isolated from every other person.
                people = _posed(est, ctx, tracked + new)
            else:
                people = tracked
            people = _dedupe(people, config.duplicate_iou)
            if lost and config.skeleton_agreement > 0:
                kept = _kept_on_skeletons(est["detector"].skeletons(ctx), lost, records, people, ctx,
                                          config.skeleton_agreement)
                people += [person for _, person in kept]
                for track_id, _ in kept:
                    on_skeletons.setdefault(track_id, []).append(index)
            t3 = time.perf_counter()
            depth = est["depth"].estimate(ctx)
            if depth is not None:
                depth = np.asarray(depth, dtype=np.float32)
                if depth.shape != ctx.size:
                    raise ValueError(f"the depth estimator {names['depth']!r} returned shape {depth.shape}, "
                                     f"expected the frame's {ctx.size}")
                step = MASK_DOWNSAMPLE
                depth_maps.append(depth[step // 2::step, step // 2::step])
            t4 = time.perf_counter()
            observations = [Observation(p.box, p.keypoints, rough_location(p.keypoints, p.keypoints3d, intrinsics),
                                        appearance_descriptor(image, p.box, p.mask, p.mask_box)) for p in people]
            track_ids = tracker.update(observations)
            t5 = time.perf_counter()
            # Body estimators that read pixels see every person of the frame now (isolated from the others).
            regressed = est["body"].observe(ctx, people) if est["body"].reads_images else [None] * len(people)
            if len(regressed) != len(people):
                raise ValueError(f"the body estimator {names['body']!r} returned {len(regressed)} results for "
                                 f"{len(people)} people")
            for track_id, person, result, obs in zip(track_ids, people, regressed, observations):
                # The mask is kept packed (an eighth of the bytes): a long video's masks add up.
                mask = (pack_mask(person.mask), person.mask_box) \
                    if config.save_masks and person.mask is not None else None
                records.setdefault(track_id, []).append((index, replace(person, mask=None, mask_box=None), result,
                                                         mask))
                # Keypoint colours only feed the colour-change split: not read when it is off.
                colours = pose_colour_descriptor(image, person.keypoints) if config.merge.colour_window else None
                cues.setdefault(track_id, []).append((obs.location, obs.appearance, colours))
            t6 = time.perf_counter()
            people_mask = _people_mask(people, ctx.size) if motion.enabled or config.save_masks else None
            t7 = time.perf_counter()
            if motion.enabled:
                gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
                if previous is not None and previous[2]:
                    ids, pixels, heights = zip(*previous[2])
                    flow = ground_flow(previous[0], gray, np.concatenate(pixels), np.repeat(heights, 4),
                                       previous[1], motion).reshape(-1, 4, 2)
                    for track_id, f in zip(ids, flow):
                        flows.setdefault(track_id, {})[index - 1] = f
                previous = (gray, people_mask, [
                    (track_id, contact_pixels(p.keypoints[None], motion.min_confidence)[0], p.box[3] - p.box[1])
                    for track_id, p in zip(track_ids, people)])
            seconds["ground_motion"] += time.perf_counter() - t7
            seconds["body"] += t6 - t5
            seconds["tracked_patches"] += t1 - t0
            seconds["detect"] += t2 - t1
            seconds["new_patches"] += t3 - t2
            seconds["depth"] += t4 - t3
            seconds["track"] += t5 - t4
            if config.save_masks:
                frame_masks.append(_pack_frame_mask(people_mask))
            people_per_frame.append(len(people))
            num_frames = index + 1
            if progress:
                progress(index)

        for track_id, frames in sorted(on_skeletons.items()):
            LOG.info("track %d kept on the detector's network skeleton where its pose search found nobody: frames %s",
                     track_id, index_ranges(np.array(frames)))
        t0 = time.perf_counter()
        confirmed = sorted(i for i in records if i in tracker.confirmed_ids())
        _hand_back_slides(confirmed, records, cues, flows, config.merge)
        apart = _split_colour_changes(confirmed, records, cues, flows, fps, config.merge)
        merged = merge_track_splits([_segment(i, records[i], cues[i]) for i in confirmed], fps, config.merge, apart)
        joined: dict[int, list] = {}
        joined_flows: dict[int, dict[int, np.ndarray]] = {}
        for track_id in confirmed:
            joined.setdefault(merged[track_id], []).extend(records[track_id])
            joined_flows.setdefault(merged[track_id], {}).update(flows.get(track_id, {}))
        seconds["merge"] = time.perf_counter() - t0
        tracks = []
        for track_id, entries in sorted(joined.items()):
            entries = sorted(entries, key=lambda entry: entry[0])
            tracks.append(_finish_track(track_id, entries, est, names, intrinsics, fps, config, seconds,
                                        joined_flows[track_id]))
        if 0 < len(depth_maps) < num_frames:
            raise ValueError(f"the depth estimator {names['depth']!r} gave maps for {len(depth_maps)} of "
                             f"{num_frames} frames; it must give one for every frame or none")
    finally:
        for e in est.values():
            e.close()
    return PerceptionResult(source, float(fps), (height, width), intrinsics, num_frames, tracks, names,
                            seconds, np.stack(frame_masks) if frame_masks else None,
                            np.array(people_per_frame, dtype=np.int64),
                            np.stack(depth_maps) if depth_maps else None,
                            {i: j for i, j in merged.items() if i != j})


def _move_frames(records: dict, cues: dict, flows: dict, source: int, target: int, moving: set,
                 dropping: set) -> None:
    """Moves the records, cues and ground flows of `source`'s frames in `moving` to `target` (kept in frame order
    beside what target holds) and drops those of its frames in `dropping`."""
    pairs = [pair for pair in zip(records[source], cues[source]) if pair[0][0] not in dropping]
    moved = [pair for pair in pairs if pair[0][0] in moving]
    kept = [pair for pair in pairs if pair[0][0] not in moving]
    joined = sorted(list(zip(records.get(target, []), cues.get(target, []))) + moved, key=lambda pair: pair[0][0])
    for track_id, rows in ((source, kept), (target, joined)):
        records[track_id], cues[track_id] = [r for r, _ in rows], [c for _, c in rows]
    source_flows = flows.get(source, {})
    for frame in dropping:
        source_flows.pop(frame, None)
    for frame in sorted(moving & set(source_flows)):
        flows.setdefault(target, {})[frame] = source_flows.pop(frame)


def _hand_back_slides(track_ids: list[int], records: dict, cues: dict, flows: dict,
                      config: TrackMergeConfig) -> list[tuple[int, int, list[int], list[int]]]:
    """Moves the frames of tracks that slid onto a person coming back (m3c.perception.track_merge.hand_back_slides)
    to that person's track, with their cues and ground flows, and drops the slides' blended frames; returns the
    moves."""
    keypoints = {i: {entry[0]: entry[1].keypoints for entry in records[i]} for i in track_ids}
    moves = hand_back_slides(keypoints, config)
    for source, target, frames, blends in moves:
        _move_frames(records, cues, flows, source, target, set(frames), set(blends))
        LOG.info("track %d had slid onto the person of track %d: frames handed to it: %s; blends of the two people "
                 "dropped: %s", source, target, index_ranges(np.array(frames)) or "none",
                 index_ranges(np.array(blends)) or "none")
    return moves


def _split_colour_changes(track_ids: list[int], records: dict, cues: dict, flows: dict, fps: float,
                          config: TrackMergeConfig) -> set[frozenset]:
    """Splits the tracks whose keypoint colours changed for good as their own person came back as a new track
    (m3c.perception.track_merge.split_colour_changes): the frames from the change go to a new id (appended to
    track_ids) with their cues and ground flows, the blended frames are dropped; returns the pairs of parts."""
    colours = {i: {entry[0]: cue[2] for entry, cue in zip(records[i], cues[i])} for i in track_ids}
    apart = set()
    for source, new, first, dropped in split_colour_changes(colours, fps, config):
        target = max(records) + 1  # every track id, confirmed or not, is a key of records
        _move_frames(records, cues, flows, source, target, {entry[0] for entry in records[source]
                                                             if entry[0] >= first}, set(dropped))
        track_ids.append(target)
        apart.add(frozenset((source, target)))
        LOG.info("track %d split at frame %d (its colours changed as track %d came in; %d blended frames dropped): "
                 "frames from there are track %d", source, first, new, len(dropped), target)
    return apart


def _segment(track_id: int, entries: list, cues: list) -> TrackSegment:
    """A track's frames, locations and descriptors for the merge rule (NaN rows where a cue is missing)."""
    locations = np.array([np.full(3, np.nan) if cue[0] is None else cue[0] for cue in cues], dtype=np.float64)

    def descriptors(column: int) -> np.ndarray:
        size = next((len(cue[column]) for cue in cues if cue[column] is not None), 1)
        return np.array([np.full(size, np.nan) if cue[column] is None else cue[column] for cue in cues],
                        dtype=np.float64)

    return TrackSegment(track_id, np.array([entry[0] for entry in entries]), locations, descriptors(1),
                        descriptors(2))


def _posed_each(est: dict, ctx: FrameContext, people: list[Person]) -> list[Person | None]:
    """Segmentation, then 2D pose, one result per person: None where nobody with keypoints was found."""
    people = est["segmenter"].segment(ctx, people)
    return [p if p is not None and p.keypoints is not None else None for p in est["pose2d"].estimate(ctx, people)]


def _posed(est: dict, ctx: FrameContext, people: list[Person]) -> list[Person]:
    """Segmentation, then 2D pose; people without keypoints are dropped."""
    return [p for p in _posed_each(est, ctx, people) if p is not None]


def _kept_on_skeletons(skeletons: list[np.ndarray], lost: list[int], records: dict, people: list[Person],
                       ctx: FrameContext, tolerance: float) -> list[tuple[int, Person]]:
    """(track, person) for the tracks whose pose search found nobody on their patch this frame while the
    detector's multi-person network still sees them (m3c.perception.paf.skeletons_for_lost_tracks): the network's
    skeleton as their keypoints (no 3D keypoints: the body fit takes the 2D ones alone there), a mask drawn from
    it."""
    last = {i: records[i][-1][1].keypoints for i in lost if records.get(i)}
    found = [p.keypoints for p in people if p.keypoints is not None]
    fit = BodyFitConfig()  # the keypoints a frame needs to be fitted at all
    kept = []
    for track_id, index in sorted(skeletons_for_lost_tracks(skeletons, last, found, tolerance, fit.min_keypoints,
                                                            fit.min_confidence).items()):
        keypoints = skeletons[index]
        box = skeleton_box(keypoints, ctx.size)
        if box is None:
            continue
        mask, mask_box = skeleton_mask(keypoints, box)
        seen = keypoints[:, 2] > 0
        kept.append((track_id, Person(box, float(keypoints[seen, 2].mean()), keypoints, None, mask, mask_box,
                                      {"detector": "tracker", "segmenter": "skeleton", "pose2d": "paf"})))
    return kept


def _finish_track(track_id: int, entries: list, est: dict, names: dict, intrinsics: np.ndarray, fps: float,
                  config: PerceptionConfig, seconds: dict, flows: dict[int, np.ndarray]) -> PersonTrack:
    frame_ids = np.array([f for f, _, _, _ in entries], dtype=np.int64)
    people = [p for _, p, _, _ in entries]
    n = len(people)
    # Rows: COCO-17, plus the foot points when any frame has them (zero confidence where it does not).
    K = max(len(p.keypoints) for p in people)
    keypoints = np.zeros((n, K, 3))
    keypoints3d = np.zeros((n, K, 4))
    for i, p in enumerate(people):
        keypoints[i, :len(p.keypoints)] = p.keypoints
        if p.keypoints3d is not None:
            keypoints3d[i, :len(p.keypoints3d)] = p.keypoints3d
    has3d = bool((keypoints3d[..., 3] > 0).any())
    restart = cold_starts(frame_ids, config.restart_gap)
    t0 = time.perf_counter()
    if est["body"].reads_images:
        bodies = est["body"].fit_track(keypoints, keypoints3d if has3d else None, intrinsics, restart, frame_ids,
                                       observations=[r for _, _, r, _ in entries])
    else:
        bodies = est["body"].fit_track(keypoints, keypoints3d if has3d else None, intrinsics, restart, frame_ids)
    t1 = time.perf_counter()
    contacts = np.zeros((n, 4))
    ground_contacts = None
    valid = bodies.valid
    if valid.sum() >= 2:
        model = est["body"].model
        betas = np.median(bodies.betas[valid], axis=0)
        joints = model.joints(bodies.pose[valid], bodies.betas[valid], bodies.transl[valid])
        speeds = None
        if config.ground_motion.enabled:
            flow_next = np.array([flows.get(int(f), np.full((4, 2), np.nan)) for f in frame_ids[valid]])
            speeds = ground_speeds(contact_pixels(keypoints[valid], config.ground_motion.min_confidence), flow_next,
                                   frame_ids[valid], fps, joints[:, list(CONTACT_JOINTS)], float(intrinsics[0]),
                                   config.ground_motion, up=estimate_up(joints))
        rest = contact_rest_heights(model, betas)
        if config.contact_depth_window is not None:
            joints = steady_depth(joints, frame_ids[valid] / fps, config.contact_depth_window)
        # Never ground_static, even in a still camera: a monocular fit's depth jitters (a standing man's feet at
        # 10 m move 1.5 m/s median in 3D, 0.08 m/s across the ray), so 3D foot speeds miss most planted feet (the
        # video benchmark's seed 0 static sequence: recall 0.12 against 0.85 with the moving camera's rule).
        contacts[valid] = est["contacts"].estimate(joints, fps, None, False, frame_ids[valid], rest,
                                                   ground_speeds=speeds)
        on_ground = est["contacts"].estimate(joints, fps, None, False, frame_ids[valid], rest, for_ground=True)
        if not np.array_equal(on_ground, contacts[valid]):  # kept where the two differ
            ground_contacts = np.zeros((n, 4))
            ground_contacts[valid] = on_ground
    t2 = time.perf_counter()
    seconds["body"] += t1 - t0
    seconds["contacts"] += t2 - t1
    sources: dict = {}
    for p in people:
        for task, name in p.sources.items():
            sources.setdefault(task, set()).add(name)
    estimators = {task: ",".join(sorted(v)) for task, v in sources.items()}
    estimators.update(body=names["body"], contacts=names["contacts"], gender=names["gender"])
    masks = [mask for _, _, _, mask in entries] if config.save_masks else None
    return PersonTrack(track_id, frame_ids, np.stack([p.box for p in people]), np.array([p.score for p in people]),
                       keypoints, keypoints3d, bodies, contacts, est["gender"].estimate(track_id, people), estimators,
                       masks, ground_contacts)


def load_result(path: str | Path) -> PerceptionResult:
    """Reads what PerceptionResult.save wrote (OUT.npz and OUT.json)."""
    path = Path(path)
    npz_path, json_path = path.with_suffix(".npz"), path.with_suffix(".json")
    for p in (npz_path, json_path):
        if not p.is_file():
            raise FileNotFoundError(f"{p} not found (PerceptionResult.save writes both OUT.npz and OUT.json)")
    summary = json.loads(json_path.read_text())
    with np.load(npz_path) as data:
        arrays = {k: data[k] for k in data.files}
    tracks = []
    for k, info in enumerate(summary["tracks"]):
        p = f"track{k}/"
        bodies = BodyFits(arrays[p + "transl"].astype(np.float64), arrays[p + "root_orient"].astype(np.float64),
                          arrays[p + "body_pose"].astype(np.float64), arrays[p + "betas"].astype(np.float64),
                          arrays[p + "reprojection_error_px"].astype(np.float64),
                          arrays[p + "keypoint_error_px"].astype(np.float64), arrays[p + "num_keypoints"],
                          arrays[p + "warm_started"], [str(s) for s in arrays[p + "fit_status"]])
        tracks.append(PersonTrack(int(arrays[p + "track_id"]), arrays[p + "frame_ids"], arrays[p + "boxes"],
                                  arrays[p + "scores"], arrays[p + "keypoints"].astype(np.float64),
                                  arrays[p + "keypoints3d"].astype(np.float64), bodies,
                                  arrays[p + "contacts"].astype(np.float64), str(arrays[p + "gender"]),
                                  dict(info["estimators"]),
                                  ground_contacts=arrays[p + "ground_contacts"].astype(np.float64)
                                  if p + "ground_contacts" in arrays else None))
    return PerceptionResult(summary["video"], float(arrays["fps"]), tuple(int(v) for v in arrays["image_size"]),
                            arrays["intrinsics"], int(arrays["num_frames"]), tracks, dict(summary["estimators"]),
                            dict(summary["seconds"]), arrays.get("frame_masks"), arrays.get("people_per_frame"),
                            arrays.get("depth"), {int(k): int(v) for k, v in summary.get("merged", {}).items()})
