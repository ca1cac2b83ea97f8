"""The ground-truth video benchmark: rendered videos of retargeted motion-capture people (m3c.synth), the real
`m3c run` pipeline on each video, and the field's metrics against the truth.

Each sequence is scored twice from the same run: the world lift before optimization (results' lift_* arrays)
and the final result (Global Opt). Beside the body metrics of m3c.eval.evaluate (PA-MPJPE, MPJPE, W-MPJPE100,
WA-MPJPE100, RTE, jitter, foot sliding of truly planted feet), it measures what a moving camera gets wrong:
  recall       detected person-frames among those where the person is in view and mostly unoccluded (%)
  ID switches  changes of the predicted track id that a ground-truth person is matched to, frame by frame; as
               in CLEAR MOT (Bernardin and Stiefelhagen 2008), a person keeps the track it was last matched to
               while that track's keypoints stay within the match distance, and the rest are matched by the
               Hungarian method: one pose that fits two overlapping people equally is not a switch
  ATE          camera centres after a Sim(3) alignment (mm), moving cameras only
  scale error  metric camera path length against the true one (%), cameras that travel at least 0.5 m
  speed error  mean horizontal pelvis speed (m3c.eval.plausibility) against the true one (%), people moving at
               least 0.2 m/s
  ground error camera height above the ground (m) and camera tilt to gravity (degrees) against the truth
The pipeline runs uncalibrated (its default intrinsics) unless asked to use the true ones.

Suites: "default" (num_sequences sequences, the camera motions in turn: the README's figures) and "hard"
(HARD_SUITE: near-still handheld cameras, slow motion, plain floors, phone optics; the same metrics in the video's
time, plus per sequence the slow motion the people's gait says against the truth and how the camera's motion was
reported).
"""

from __future__ import annotations

import json
import logging
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from m3c.body import BodyModel
from m3c.eval import metrics as M
from m3c.eval.evaluate import SequenceResult, aggregate, arm_errors, evaluate_sequence
from m3c.eval.matching import common_frames
from m3c.eval.plausibility import track_plausibility
from m3c.eval.retarget import RetargetedMotion
from m3c.eval.tracks import EvalTrack, body_eval_track
from m3c.synth.cameras import CAMERA_KINDS, EXTRA_CAMERA_KINDS
from m3c.synth.sequence import SequenceSpec, SyntheticVideo, make_video

LOG = logging.getLogger("m3c.eval.video_benchmark")
METHODS = ("Lift", "Global Opt")
PEOPLE_PATTERN = (1, 3, 2)  # people in sequence i: PEOPLE_PATTERN[i % 3], capped by max_people
PELVIS = (1, 2)  # the hips: the evaluation pelvis (as m3c eval)
# A person counts as visible (for recall) when this many COCO keypoints are in the image and at most this share
# of its silhouette is hidden by others; a detection matches when its keypoints lie within this share of the
# person's image height on average.
VISIBLE_KEYPOINTS = 12
MAX_OCCLUSION = 0.3
MATCH_DISTANCE = 0.2
MIN_CAMERA_PATH = 0.5  # metres: a true camera that never gets this far from its start gets no scale error
MIN_PERSON_SPEED = 0.2  # m/s: slower true people get no speed error
SUITES = ("default", "hard")
# The hard suite: (camera, people, slow motion, floor, degraded, crowd). Slow motion 4 gets twice the frames (two
# strides of a walk need about 9 s of video at 1/4 speed). The crowds (unscored walkers, m3c.synth.people.place_crowd)
# came after the first nine, which keep their videos and figures.
HARD_SUITE = (
    ("still", 2, 1.0, "textured", False, 0),
    ("still", 1, 1.0, "plain", True, 0),
    ("follow", 1, 2.0, "textured", False, 0),
    ("tracking", 1, 4.0, "textured", False, 0),
    ("handheld", 2, 1.0, "plain", False, 0),
    ("static", 1, 2.0, "textured", True, 0),
    ("pan", 3, 1.0, "plain", False, 0),
    ("orbit", 2, 2.0, "textured", True, 0),
    ("still", 1, 4.0, "plain", False, 0),
    ("still", 2, 1.0, "textured", False, 20),   # a near-still phone on a busy square
    ("follow", 1, 1.0, "plain", False, 12),     # a tracking shot past passers-by, on a plain floor
    ("pan", 2, 1.0, "textured", True, 25),      # a pan across a crowd, phone optics
    ("tracking", 1, 1.0, "glossy", False, 0),   # a jogger in a sports hall, its polished floor mirroring her
)


@dataclass
class VideoBenchmarkConfig:
    num_sequences: int = 7
    num_frames: int = 150
    cameras: tuple = CAMERA_KINDS
    max_people: int = 3
    seed: int = 0
    width: int = 960
    height: int = 540
    fps: float = 30.0
    supersample: int = 1
    clip_paths: tuple = ()  # retargeted .npz motions; empty: the shipped CMU clips
    pipeline_config: str | None = None
    overrides: tuple = ()  # NODE.KEY=VALUE settings for every run
    known_intrinsics: bool = False  # give the pipeline the true intrinsics (else it runs uncalibrated)
    render_only: bool = False
    suite: str = "default"  # SUITES; "hard" ignores num_sequences and cameras (HARD_SUITE)
    only: tuple = ()  # sequence indices to run (empty: all); the others are neither rendered nor run

    def validate(self) -> None:
        if self.suite not in SUITES:
            raise ValueError(f"suite must be one of {', '.join(SUITES)}, got {self.suite!r}")
        count = len(HARD_SUITE) if self.suite == "hard" else self.num_sequences
        if any(not 0 <= int(i) < count for i in self.only):
            raise ValueError(f"--only takes sequence indices 0-{count - 1}, got {list(self.only)}")
        if self.num_sequences < 1:
            raise ValueError(f"the video benchmark needs at least 1 sequence, got {self.num_sequences}")
        if self.num_frames < 10:
            raise ValueError(f"sequences need at least 10 frames, got {self.num_frames}")
        if not 1 <= self.max_people <= 3:
            raise ValueError(f"max_people must be 1, 2 or 3, got {self.max_people}")
        kinds = CAMERA_KINDS + EXTRA_CAMERA_KINDS
        unknown = [c for c in self.cameras if c not in kinds]
        if unknown or not self.cameras:
            raise ValueError(f"camera motions must be among {', '.join(kinds)}, got {list(self.cameras)}")
        if self.supersample < 1:
            raise ValueError(f"supersample must be >= 1, got {self.supersample}")
        for spec in self.specs():  # sizes and rates, before any sequence runs
            spec.validate()

    def specs(self) -> list[SequenceSpec]:
        specs = self._all_specs()
        return [s for s in specs if s.index in set(self.only)] if self.only else specs

    def _all_specs(self) -> list[SequenceSpec]:
        if self.suite == "hard":
            return [
                SequenceSpec(i, camera, min(people, self.max_people),
                             self.num_frames * (2 if slow >= 4 else 1), self.fps, self.width, self.height,
                             self.seed, self.supersample, slow, floor, degrade, crowd)
                for i, (camera, people, slow, floor, degrade, crowd) in enumerate(HARD_SUITE)
            ]
        return [
            SequenceSpec(
                i,
                self.cameras[i % len(self.cameras)],
                min(PEOPLE_PATTERN[i % 3], self.max_people),
                self.num_frames,
                self.fps,
                self.width,
                self.height,
                self.seed,
                self.supersample,
            )
            for i in range(self.num_sequences)
        ]


@dataclass
class MethodScore:
    body: SequenceResult
    camera: dict = field(
        default_factory=dict
    )  # ate_mm, scale_error_pct, ground_height_error_m, tilt_error_deg
    speed_error_pct: list = field(default_factory=list)  # per matched moving person
    # Per matched moving person: the median speed of its slower foot (m/s; a walker's planted foot, ~0 when the
    # feet do not slide; m3c.eval.plausibility's slow_foot_speed_mps)
    slow_foot_mps: list = field(default_factory=list)


@dataclass
class SequenceScore:
    name: str
    camera_motion: str
    num_people: int
    folder: str
    render_seconds: float = 0.0
    node_seconds: dict = field(default_factory=dict)
    detection: dict = field(default_factory=dict)  # visible, detected, id_switches, person_frames
    methods: dict = field(default_factory=dict)  # method -> MethodScore
    error: str = ""
    # What the run said about time and camera motion: true and found slow motion (results.json video.time_scale),
    # the camera as reported (static, rotation only, or the scale's source) and its true largest travel (m).
    world: dict = field(default_factory=dict)


# Scoring --------------------------------------------------------------------------------------------------------
def truth_tracks(model: BodyModel, truth: dict) -> list[EvalTrack]:
    n = truth["world_from_cam"].shape[0]
    return [
        body_eval_track(
            model,
            np.arange(n),
            truth["root_orient"][p],
            truth["body_pose"][p],
            truth["betas"][p],
            truth["transl"][p],
            truth["world_from_cam"],
        )
        for p in range(len(truth["betas"]))
    ]


def predicted_tracks(model: BodyModel, arrays: dict, method: str) -> list[EvalTrack]:
    """EvalTracks (indexed by truth frame ids) of every result track for one method."""
    lift = method == "Lift"
    root = arrays["lift_world_root_orient" if lift else "world_root_orient"]
    transl = arrays["lift_world_transl" if lift else "world_transl"]
    body = arrays["lift_body_pose" if lift else "body_pose"]
    betas = arrays["lift_betas" if lift else "betas"]
    cams = arrays["lift_world_from_cam" if lift else "world_from_cam"].astype(np.float64)
    frame_ids = arrays["frame_ids"]
    out = []
    for p in range(len(arrays["track_ids"])):
        t = np.flatnonzero(arrays["valid"][p])
        out.append(
            body_eval_track(model, frame_ids[t], root[p, t], body[p, t], betas[p], transl[p, t], cams[t])
        )
    return out


def detection_scores(truth: dict, arrays: dict) -> dict:
    """Frame-by-frame matching of detections (results' keypoints where a track was detected) to the true
    people: recall over visible people and identity switches (CLEAR MOT matching: last correspondences kept
    while valid, the rest by the Hungarian method), each switch also listed (switch_events: frame, true person,
    the track id it left, the one it took), so a sequence's switches can be looked up in its video. Where the
    results carry contacts, the planted feet of each matched detection against the true ones (a foot planted when
    its ankle or toe joint is, probability > 0.5): contact_hits (both say planted), contact_predicted,
    contact_true, counted per foot and frame."""
    n_true = truth["keypoints_2d"].shape[0]
    silhouette = truth["silhouette_pixels"]
    occlusion = 1.0 - truth["visible_pixels"] / np.maximum(silhouette, 1)
    visible = (
        (truth["keypoints_in_image"].sum(-1) >= VISIBLE_KEYPOINTS)
        & (silhouette > 0)
        & (occlusion <= MAX_OCCLUSION)
    )
    ids = arrays["track_ids"]
    last = [None] * n_true
    switches = detected = matched_frames = 0
    switch_events = []
    with_contacts = "contacts" in arrays and "contacts" in truth
    contacts = np.zeros(3, dtype=np.int64)  # hits, predicted, true
    for t, frame in enumerate(arrays["frame_ids"]):
        tracks = np.flatnonzero(arrays["visible"][:, t])
        if len(tracks) == 0:
            continue
        cost = np.full((n_true, len(tracks)), np.inf)
        for p in range(n_true):
            inside = truth["keypoints_in_image"][p, frame]
            if inside.sum() < 3:
                continue
            gt = truth["keypoints_2d"][p, frame]
            height = max(float(np.ptp(gt[inside, 1])), 20.0)
            for k, track in enumerate(tracks):
                kp = arrays["keypoints_2d"][track, t]
                use = inside & (kp[:, 2] >= 0.3)
                if use.sum() >= 3:
                    cost[p, k] = np.linalg.norm(kp[use, :2] - gt[use], axis=-1).mean() / height
        pairs = _kept_pairs(cost, [ids[k] for k in tracks], last)
        free_p = [p for p in range(n_true) if p not in {a for a, _ in pairs}]
        free_k = [k for k in range(len(tracks)) if k not in {b for _, b in pairs}]
        rest = cost[np.ix_(free_p, free_k)]
        rows, cols = linear_sum_assignment(np.where(np.isfinite(rest), rest, 1e6))
        pairs += [(free_p[r], free_k[c]) for r, c in zip(rows, cols)]
        for p, k in pairs:
            if cost[p, k] > MATCH_DISTANCE:
                continue
            matched_frames += 1
            detected += int(visible[p, frame])
            if last[p] is not None and last[p] != ids[tracks[k]]:
                switches += 1
                switch_events.append({"frame": int(frame), "person": int(p), "from_track": int(last[p]),
                                      "to_track": int(ids[tracks[k]])})
            last[p] = ids[tracks[k]]
            if with_contacts:
                planted = _planted_feet(arrays["contacts"][tracks[k], t])
                true = _planted_feet(truth["contacts"][p, frame])
                contacts += [int((planted & true).sum()), int(planted.sum()), int(true.sum())]
    frames = arrays["frame_ids"]
    out = {
        "visible": int(visible[:, frames].sum()),
        "detected": int(detected),
        "id_switches": int(switches),
        "switch_events": switch_events,
        "matched_person_frames": int(matched_frames),
        "person_frames": int(visible.shape[0] * len(frames)),
    }
    if with_contacts:
        out.update(contact_hits=int(contacts[0]), contact_predicted=int(contacts[1]), contact_true=int(contacts[2]))
    return out


def _planted_feet(contacts: np.ndarray) -> np.ndarray:
    """(2,) bool, left and right foot planted, from CONTACT_JOINTS' probabilities (ankles 7, 8; feet 10, 11)."""
    c = np.nan_to_num(np.asarray(contacts, dtype=np.float64))
    return np.maximum(c[[0, 1]], c[[2, 3]]) > 0.5


def _kept_pairs(cost: np.ndarray, track_ids: list, last: list) -> list[tuple[int, int]]:
    """(person, column) pairs of the people whose last matched track is among the columns and still within
    MATCH_DISTANCE (CLEAR MOT's kept correspondences), the closer first where two claim one track."""
    claims = sorted((cost[p, track_ids.index(i)], p, track_ids.index(i)) for p, i in enumerate(last)
                    if i is not None and i in track_ids and cost[p, track_ids.index(i)] <= MATCH_DISTANCE)
    pairs, taken = [], set()
    for _, p, k in claims:
        if k not in taken:
            pairs.append((p, k))
            taken.add(k)
    return pairs


def camera_travel(world_from_cam: np.ndarray) -> float:
    """Metres: the farthest a camera gets from its first position."""
    centres = world_from_cam[:, :3, 3]
    return float(np.linalg.norm(centres - centres[0], axis=1).max())


def camera_scores(pred_world_from_cam: np.ndarray, true_world_from_cam: np.ndarray) -> dict:
    """Camera errors of one method: ATE after Sim(3) (moving cameras), scale error (the Sim(3) alignment's scale:
    the path length would count a trajectory's jitter as scale), camera height above the ground (y = 0 in both
    worlds) and tilt of the camera to gravity (world y)."""
    out = {}
    # How far the true camera gets, not its path's length: a hand's shake adds path but no baseline to scale.
    travel = camera_travel(true_world_from_cam)
    pred_path = float(np.linalg.norm(np.diff(pred_world_from_cam[:, :3, 3], axis=0), axis=-1).sum())
    if travel >= MIN_CAMERA_PATH and np.ptp(pred_world_from_cam[:, :3, 3], axis=0).max() <= 1e-9:
        # Held fixed (the odometry's camera that turned in place) while the truth moved: no similarity maps a point
        # onto a path; the best a point does is the path's mean (ATE: the path's spread), its scale is 0.
        spread = true_world_from_cam[:, :3, 3] - true_world_from_cam[:, :3, 3].mean(axis=0)
        out["ate_mm"] = float(np.sqrt((spread ** 2).sum(axis=-1).mean())) * M.M_TO_MM
        out["scale_error_pct"] = -100.0
    elif travel >= MIN_CAMERA_PATH:
        out["ate_mm"] = float(np.sqrt((M.camera_ate(pred_world_from_cam, true_world_from_cam) ** 2).mean()))
        align, _, _ = M.umeyama(pred_world_from_cam[:, :3, 3], true_world_from_cam[:, :3, 3], with_scale=True)
        out["scale_error_pct"] = 100.0 * (1.0 / align - 1.0)
    out["camera_path_m"] = pred_path
    out["ground_height_error_m"] = float(
        np.abs(pred_world_from_cam[:, 1, 3] - true_world_from_cam[:, 1, 3]).mean()
    )
    up_pred = pred_world_from_cam[:, 1, :3]  # world y in camera coordinates: row 1 of R
    up_true = true_world_from_cam[:, 1, :3]
    cos = np.clip((up_pred * up_true).sum(-1) / np.linalg.norm(up_pred, axis=-1), -1.0, 1.0)
    out["tilt_error_deg"] = float(np.degrees(np.arccos(cos)).mean())
    return out


def score_method(
    model: BodyModel, truth: dict, gt: list[EvalTrack], arrays: dict, method: str, name: str
) -> MethodScore:
    fps = float(truth["fps"])
    pred = predicted_tracks(model, arrays, method)
    body = evaluate_sequence(gt, pred, fps, pelvis=PELVIS, name=name)
    cams = arrays["lift_world_from_cam" if method == "Lift" else "world_from_cam"].astype(np.float64)
    camera = camera_scores(cams, truth["world_from_cam"][arrays["frame_ids"]])
    speeds, slow_feet = [], []
    for match in body.matching.matches:
        ig, ip = common_frames(gt[match.gt].frames, pred[match.pred].frames)
        if len(ig) < fps:  # under a second: no meaningful speed
            continue
        true_speed = track_plausibility(gt[match.gt].joints_world[ig], fps)["mean_speed_mps"]
        if true_speed >= MIN_PERSON_SPEED:
            figures = track_plausibility(pred[match.pred].joints_world[ip], fps)
            speeds.append(100.0 * (figures["mean_speed_mps"] / true_speed - 1.0))
            if figures.get("slow_foot_speed_mps") is not None:
                slow_feet.append(float(figures["slow_foot_speed_mps"]))
    return MethodScore(body, camera, speeds, slow_feet)


def score_results(model: BodyModel, truth: dict, arrays: dict, name: str) -> tuple[dict, dict]:
    """(detection scores, method -> MethodScore) of one run's results against the truth."""
    gt = truth_tracks(model, truth)
    return detection_scores(truth, arrays), {
        m: score_method(model, truth, gt, arrays, m, name) for m in METHODS
    }


# Running ----------------------------------------------------------------------------------------------------------
def pipeline_config(config: VideoBenchmarkConfig, video: SyntheticVideo):
    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline import PipelineConfig, parse_override

    register_builtin_nodes()
    pipeline = (
        PipelineConfig.from_yaml(Path(config.pipeline_config))
        if config.pipeline_config
        else PipelineConfig.default()
    )
    overrides = dict(parse_override(item) for item in config.overrides)
    if config.known_intrinsics:
        overrides["camera.intrinsics"] = [float(v) for v in video.truth()["intrinsics"]]
    return pipeline.with_overrides(overrides) if overrides else pipeline


def source_coverage(scale: dict, lift_scale_error_pct: float | None) -> list[dict]:
    """Each scale source's value against the truth: the lift's cameras carry the fused value, so the true scale
    is value / (1 + the lift's scale error); a source covers the truth when its log error is within 2 sigma (a
    person-size source's sigma with the size's shared PERSON_SIZE_SIGMA). Empty without a measured truth."""
    from m3c.vo.scale import PERSON_SIZE_SIGMA

    if lift_scale_error_pct is None or not scale.get("value") or lift_scale_error_pct <= -100.0:
        return []
    true = float(scale["value"]) / (1.0 + lift_scale_error_pct / 100.0)
    out = []
    for o in scale.get("observations") or []:
        if o.get("value") is None or o.get("sigma") is None:
            continue
        sigma = float(np.hypot(o["sigma"], PERSON_SIZE_SIGMA)) if o.get("person_size", True) else float(o["sigma"])
        error = float(np.log(o["value"] / true))
        out.append({"source": o["source"], "error_pct": 100.0 * float(np.expm1(error)), "sigma": sigma,
                    "covered": bool(abs(error) <= 2.0 * sigma),
                    "set_aside": bool((o.get("detail") or {}).get("set_aside", False))})
    return out


def run_sequence(
    model: BodyModel,
    clips: list[RetargetedMotion],
    spec: SequenceSpec,
    config: VideoBenchmarkConfig,
    out_dir: Path,
    show_progress: bool = True,
    log=None,
) -> SequenceScore:
    from m3c.io.results import load_results
    from m3c.pipeline import Runner
    from m3c.pipeline.progress import Progress

    with Progress(f"{spec.name}: render", spec.num_frames, LOG, enabled=show_progress) as progress:
        video = make_video(model, clips, spec, out_dir / "videos", log, progress)
    score = SequenceScore(spec.name, spec.camera, spec.num_people, str(video.folder), video.render_seconds)
    if config.render_only:
        return score
    run_dir = out_dir / "runs" / video.folder.name
    report = Runner(
        pipeline_config(config, video), run_dir, {"video": video.video}, show_progress=show_progress
    ).run(["results"])
    score.node_seconds = {r.name: r.seconds for r in report.records if r.status == "ran"}
    summary, arrays = load_results(run_dir)
    truth = video.truth()
    score.detection, score.methods = score_results(model, truth, arrays, spec.name)
    time_scale = summary["video"].get("time_scale") or {}
    scale = summary["camera"].get("scale_estimate") or {}
    camera = summary["camera"]
    score.world = {"slow_motion_true": float(truth.get("slow_motion", 1.0)),
                   "slow_motion_found": time_scale.get("factor"),
                   "slow_motion_confident": time_scale.get("confident"),
                   "camera_reported": "static" if camera["static"] else camera["scale_source"],
                   "camera_travel_m": camera_travel(truth["world_from_cam"]),
                   "scale_sigma": scale.get("sigma"), "scale_confidence": scale.get("confidence"),
                   "scale_sources": source_coverage(scale, score.methods["Lift"].camera.get("scale_error_pct"))}
    if log:
        opt = score.methods["Global Opt"]
        log(
            f"{spec.name}: {len(arrays['track_ids'])} tracks for {spec.num_people} people, W-MPJPE100 "
            f"{_fmt(opt.body.mean('w_mpjpe'))} mm, scale error {_fmt(opt.camera.get('scale_error_pct'))} %"
        )
    return score


def _fmt(value, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


@dataclass
class VideoBenchmarkReport:
    config: VideoBenchmarkConfig
    sequences: list[SequenceScore]
    body_model: str
    seconds: float = 0.0

    def scored(self) -> list[SequenceScore]:
        return [s for s in self.sequences if s.methods]

    def overall(self, method: str) -> dict:
        seqs = self.scored()
        out = aggregate([s.methods[method].body for s in seqs])
        visible = sum(s.detection["visible"] for s in seqs)
        out["recall_pct"] = 100.0 * sum(s.detection["detected"] for s in seqs) / visible if visible else None
        frames = sum(s.detection["person_frames"] for s in seqs)
        out["id_switches"] = sum(s.detection["id_switches"] for s in seqs) if seqs else None
        out["id_switches_per_1000"] = 1000.0 * out["id_switches"] / frames if frames else None
        hits, predicted, true = (sum(s.detection.get(k, 0) for s in seqs)
                                 for k in ("contact_hits", "contact_predicted", "contact_true"))
        out["contact_precision"] = hits / predicted if predicted else None
        out["contact_recall"] = hits / true if true else None
        for key in ("ate_mm", "scale_error_pct", "ground_height_error_m", "tilt_error_deg"):
            values = [
                abs(s.methods[method].camera[key])
                if key == "scale_error_pct"
                else s.methods[method].camera[key]
                for s in seqs
                if key in s.methods[method].camera
            ]
            out[key if key != "scale_error_pct" else "abs_scale_error_pct"] = (
                float(np.mean(values)) if values else None
            )
        speeds = [abs(v) for s in seqs for v in s.methods[method].speed_error_pct]
        out["abs_speed_error_pct"] = float(np.mean(speeds)) if speeds else None
        out["arms"] = arm_errors([s.methods[method].body for s in seqs])
        return out

    def row(self, seq: SequenceScore, method: str) -> dict:
        score = seq.methods[method]
        det = seq.detection
        row = {
            k: score.body.mean(k)
            for k in ("pa_mpjpe", "mpjpe", "w_mpjpe", "wa_mpjpe", "rte", "jitter", "foot_sliding")
        }
        row["recall_pct"] = 100.0 * det["detected"] / det["visible"] if det["visible"] else None
        row["id_switches"] = det["id_switches"]
        row.update(score.camera)
        row["speed_error_pct"] = float(np.mean(score.speed_error_pct)) if score.speed_error_pct else None
        row["slow_foot_mps"] = float(np.median(score.slow_foot_mps)) if score.slow_foot_mps else None
        row["matched"] = len(score.body.matching.matches)
        row["arms"] = arm_errors([score.body])
        return row

    def table(self) -> str:
        cols = [
            ("Recall%", "recall_pct", 8, 1),
            ("IDsw", "id_switches", 5, 0),
            ("PA-MPJPE", "pa_mpjpe", 9, 1),
            ("MPJPE", "mpjpe", 7, 1),
            ("W-MPJPE", "w_mpjpe", 8, 0),
            ("WA-MPJPE", "wa_mpjpe", 9, 0),
            ("RTE%", "rte", 6, 1),
            ("ATE mm", "ate_mm", 7, 0),
            ("Scale%", "scale_error_pct", 7, 1),
            ("Speed%", "speed_error_pct", 7, 1),
            ("FS mm", "foot_sliding", 6, 1),
            ("Jitter", "jitter", 7, 1),
            ("Gnd m", "ground_height_error_m", 6, 2),
            ("Tilt°", "tilt_error_deg", 6, 1),
        ]
        name_w = max([len("Sequence / method")] + [len(s.name) + 3 for s in self.sequences]) + 2
        head = "Sequence / method".ljust(name_w) + "".join(t.rjust(w) for t, _, w, _ in cols)
        lines = [head, "-" * len(head)]

        def cells(values: dict) -> str:
            out = ""
            for _, key, width, digits in cols:
                v = values.get(key)
                if key == "jitter" and v is not None:
                    v = v / 10.0  # tables: 10 m/s^3
                out += ("-" if v is None else f"{v:.{digits}f}").rjust(width)
            return out

        for seq in self.sequences:
            if not seq.methods:
                lines.append(
                    f"{seq.name}^{seq.num_people}".ljust(name_w)
                    + (
                        f"  FAILED: {seq.error.splitlines()[-1] if seq.error else ''}"
                        if seq.error
                        else "  rendered only"
                    )
                )
                continue
            for method in METHODS:
                label = f"{seq.name}^{seq.num_people}" if method == METHODS[0] else f"  {method}"
                if method == METHODS[0]:
                    label += " Lift"
                lines.append(label.ljust(name_w) + cells(self.row(seq, method)))
        if self.scored():
            lines.append("-" * len(head))
            for method in METHODS:
                o = self.overall(method)
                o["scale_error_pct"], o["speed_error_pct"] = (
                    o["abs_scale_error_pct"],
                    o["abs_speed_error_pct"],
                )
                lines.append(f"All: {method}".ljust(name_w) + cells(o))
        return "\n".join(lines)

    def text(self) -> str:
        c = self.config
        scored = self.scored()
        frames = sum(s.detection.get("person_frames", 0) for s in scored)
        lines = [
            f"M3C video benchmark{' (suite ' + c.suite + ')' if c.suite != 'default' else ''}: "
            f"{len(self.sequences)} sequences x {c.num_frames} frames at {c.fps:g} fps, "
            f"{c.width} x {c.height}, seed {c.seed}, {'true' if c.known_intrinsics else 'default (uncalibrated)'}"
            f" intrinsics; body model {self.body_model}, 24 joints, pelvis = mean of the hips.",
            "mm unless stated (^: people). Lift: the world lift before optimization; Global Opt: the final "
            "result. Jitter in 10 m/s^3; 'All' rows: per-frame means, camera and speed errors as mean "
            "absolute values, IDsw summed.",
            "",
            self.table(),
            "",
        ]
        if scored:
            o = self.overall("Global Opt")
            lines.append(
                f"detection recall {_fmt(o['recall_pct'])} % of visible person-frames; identity switches "
                f"{o['id_switches']} ({_fmt(o['id_switches_per_1000'], 2)} per 1000 person-frames over "
                f"{frames})."
            )
            arms = o["arms"]
            if arms is not None:
                lines.append(
                    f"arms (Global Opt, PA-aligned per joint): shoulders {arms['shoulder_mm']:.1f}, elbows "
                    f"{arms['elbow_mm']:.1f}, wrists {arms['wrist_mm']:.1f} mm (worse / shoulder "
                    f"{_fmt(arms['ratio'], 2)}); the far arm {arms['far_shoulder_mm']:.1f}, "
                    f"{arms['far_elbow_mm']:.1f}, {arms['far_wrist_mm']:.1f} mm ({_fmt(arms['far_ratio'], 2)})."
                )
            if o["contact_precision"] is not None or o["contact_recall"] is not None:
                lines.append(
                    f"planted feet (each matched person's feet per frame against the true contacts): precision "
                    f"{_fmt(o['contact_precision'], 2)}, recall {_fmt(o['contact_recall'], 2)}."
                )
        worlds = [s for s in scored if s.world]
        if worlds and c.suite != "default":
            lines.append("world (slow motion true / found by the gait, * confident; the camera's true travel and "
                         "as reported; the scale's 2-sigma interval covers the truth):")
            for s in worlds:
                w, opt = s.world, s.methods["Global Opt"].camera
                found = w["slow_motion_found"]
                error = opt.get("scale_error_pct")
                covered = "-" if error is None or w["scale_sigma"] is None else \
                    ("yes" if abs(np.log1p(error / 100.0)) <= 2 * w["scale_sigma"] else "no")
                found = "-" if found is None else f"x{found:.2f}" + ("*" if w["slow_motion_confident"] else "")
                feet = s.methods["Global Opt"].slow_foot_mps
                lines.append(f"  {s.name}: slow x{w['slow_motion_true']:g} / {found}; camera travel "
                             f"{w['camera_travel_m']:.2f} m, reported {w['camera_reported']}; scale covered "
                             f"{covered}; walkers' slower foot "
                             + (", ".join(f"{v:.2f}" for v in feet) + " m/s" if feet else "-"))
        coverage = self.scale_coverage()
        if coverage:
            lines.append("camera scale, each source against the truth (2-sigma interval covers it / sequences "
                         "measured; median |error|): " + "; ".join(
                             f"{name} {c['covered']}/{c['sequences']} ({_fmt(c['median_abs_error_pct'])} %)"
                             for name, c in coverage.items()))
        failed = [s for s in self.sequences if s.error]
        if failed:
            lines.append(f"failed: {', '.join(s.name for s in failed)}")
        stage = self.stage_seconds()
        lines.append(
            "time: " + ", ".join(f"{k} {v:.0f} s" for k, v in stage.items()) + f"; total {self.seconds:.0f} s"
        )
        return "\n".join(lines)

    def scale_coverage(self) -> dict:
        """Per scale source, and 'fused' (the lift's camera scale), over the sequences where the truth was measured:
        how many the source measured and how often its 2-sigma interval held the truth."""
        out: dict[str, dict] = {}

        def add(name: str, covered: bool, error_pct: float) -> None:
            c = out.setdefault(name, {"sequences": 0, "covered": 0, "errors": []})
            c["sequences"] += 1
            c["covered"] += int(covered)
            c["errors"].append(abs(error_pct))

        for s in self.scored():
            if not s.world:
                continue
            for o in s.world.get("scale_sources") or []:
                add(o["source"], o["covered"], o["error_pct"])
            error, sigma = s.methods["Lift"].camera.get("scale_error_pct"), s.world.get("scale_sigma")
            if error is not None and sigma is not None and error > -100.0:
                add("fused", abs(np.log1p(error / 100.0)) <= 2 * sigma, error)
        for c in out.values():
            c["median_abs_error_pct"] = float(np.median(c.pop("errors")))
        return out

    def stage_seconds(self) -> dict:
        out = {"render": sum(s.render_seconds for s in self.sequences)}
        for s in self.sequences:
            for name, sec in s.node_seconds.items():
                out[name] = out.get(name, 0.0) + sec
        return out

    def summary(self) -> dict:
        def sequence(s: SequenceScore) -> dict:
            out = {
                "name": s.name,
                "camera_motion": s.camera_motion,
                "people": s.num_people,
                "folder": s.folder,
                "render_seconds": s.render_seconds,
                "node_seconds": s.node_seconds,
                "detection": s.detection,
                "error": s.error or None,
                "world": s.world,
            }
            if s.methods:
                out["methods"] = {m: self.row(s, m) for m in METHODS}
                out["speed_error_pct"] = {m: s.methods[m].speed_error_pct for m in METHODS}
            return out

        return {
            "config": asdict(self.config),
            "body_model": self.body_model,
            "seconds": self.seconds,
            "stage_seconds": self.stage_seconds(),
            "overall": {m: self.overall(m) for m in METHODS} if self.scored() else {},
            "scale_coverage": self.scale_coverage(),
            "sequences": [sequence(s) for s in self.sequences],
        }


def run_video_benchmark(
    model: BodyModel, config: VideoBenchmarkConfig, out_dir: str | Path, log=None, show_progress: bool = True
) -> VideoBenchmarkReport:
    """Renders (once, cached under out_dir/videos) and runs (cached under out_dir/runs) every sequence; a sequence
    that fails is reported and the others go on."""
    from m3c.eval.benchmark import load_clips

    config.validate()
    clips = load_clips(config.clip_paths)
    out_dir = Path(out_dir)
    start = time.perf_counter()
    scores = []
    for spec in config.specs():
        try:
            scores.append(run_sequence(model, clips, spec, config, out_dir, show_progress, log))
        except KeyboardInterrupt:
            raise
        except Exception as err:  # a failed sequence is reported; the others go on
            if log:
                log(f"{spec.name}: FAILED: {type(err).__name__}: {err}")
            scores.append(
                SequenceScore(
                    spec.name,
                    spec.camera,
                    spec.num_people,
                    "",
                    error=f"{type(err).__name__}: {err}\n{traceback.format_exc()}",
                )
            )
    return VideoBenchmarkReport(config, scores, getattr(model.data, "name", ""), time.perf_counter() - start)


def write_json(report: VideoBenchmarkReport, path: str | Path, provenance: dict | None = None) -> None:
    """The report's summary as JSON; provenance (the command, M3C's version, the commit) goes with it."""
    from m3c.io.atomic import atomic_path

    summary = report.summary() if provenance is None else {**report.summary(), "provenance": provenance}
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(summary, indent=1, default=float) + "\n")


__all__ = [
    "MethodScore",
    "SequenceScore",
    "VideoBenchmarkConfig",
    "VideoBenchmarkReport",
    "camera_scores",
    "detection_scores",
    "predicted_tracks",
    "run_video_benchmark",
    "score_results",
    "truth_tracks",
    "write_json",
]
