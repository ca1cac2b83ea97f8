"""A training corpus from motion capture: every BVH of the given files, folders and tar archives retargeted
onto the body model (m3c.mocap.fast_retarget), one .npz per clip, with a held-out split by clip.

Layout of OUT (`m3c data mocap`):
    clips/<clip id>.npz   pose (T, 24, 3) axis-angle root first, transl (T, 3) (the body model's translation
                          parameter, world frame y up, ground y = 0, metres), betas (B,), contacts (T, 4) bool
                          (CONTACT_JOINTS), fps, fit_error_mm (T,), clip, source, licence, key (the cache key)
    index.json            per clip: frames, split, source, licence, fit error; the failed files and why
    split.json            {"train": [...], "held_out": [...]} clip ids
A clip's id is its path inside the archive or folder it came from, '/' replaced by '__', without .bvh. A clip
already written with the same cache key (the file's bytes, the settings, the body model) is not redone, so an
interrupted run resumes; each file is written atomically. A file that cannot be read or retargeted is reported
and listed under "failed"; the rest go on.
"""

from __future__ import annotations

import hashlib
import json
import tarfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from m3c.body import BodyModel
from m3c.io.atomic import atomic_path, save_npz_atomic
from m3c.mocap.fast_retarget import FastRetargetConfig, fast_retarget

# Every clip the benchmarks render (m3c.eval.benchmark.SHIPPED_CLIPS: CMU 131_01 and 01_01; the BVH files of
# ../shared/data/mocap that `m3c eval video-benchmark --mocap` renders): never in a training corpus, whatever
# folder or archive they come from. Matched on the file name without .bvh.
BENCHMARK_CLIP_NAMES = frozenset({
    "131_01", "01_01", "dataset-1_dash_active_001", "dataset-1_run_active_001", "dataset-1_run_happy_001",
    "dataset-1_walk_active_001", "dataset-1_walk_happy_001", "dataset-1_walk_normal_001",
    "dataset-2_run_normal_001", "dataset-2_run_normal_002", "dataset-2_walk_normal_001",
    "dataset-2_walk_normal_002",
})
# The joints whose ground contact is labelled: SMPL indices and names.
CONTACT_JOINTS = (7, 8, 10, 11)
CONTACT_NAMES = ("left_ankle", "right_ankle", "left_foot", "right_foot")
LICENCES = {
    "bandai_namco": "CC BY-NC 4.0 (Bandai Namco Research Motiondataset; non-commercial)",
    "cmu": "CMU Graphics Lab Motion Capture Database terms (research and commercial use; no resale of the "
           "data)",
}
_ARCHIVES = (".tar.xz", ".tar.gz", ".tgz", ".tar.bz2", ".tar")
FORMAT_VERSION = 1  # part of the cache key: bump when the retarget or the stored fields change


@dataclass
class CorpusConfig:
    retarget: FastRetargetConfig = field(default_factory=FastRetargetConfig)
    held_out_percent: float = 10.0     # share of clips (by a hash of the clip id) kept out of training
    min_frames: int = 15               # shorter clips (at the output rate) are skipped
    contact_height: float = 0.06       # m above the clip's lowest height of that joint
    contact_speed: float = 0.3         # m/s
    exclude: frozenset = BENCHMARK_CLIP_NAMES


def held_out(clip_id: str, percent: float) -> bool:
    """Deterministic held-out membership of a clip: the first 8 hex digits of SHA-1(clip id) below
    percent%."""
    return int(hashlib.sha1(clip_id.encode()).hexdigest()[:8], 16) < percent / 100.0 * 16 ** 8


def foot_contacts(joints: np.ndarray, fps: float, height: float, speed: float) -> np.ndarray:
    """(T, 4) bool: each CONTACT_JOINTS joint within `height` of its lowest (5th percentile) height and slower
    than `speed` (central differences, horizontal and vertical together). joints: (T, 24, 3) world, y up."""
    feet = joints[:, list(CONTACT_JOINTS)]
    vel = np.gradient(feet, axis=0) * fps if len(feet) > 1 else np.zeros_like(feet)
    low = np.quantile(feet[:, :, 1], 0.05, axis=0)
    return (feet[:, :, 1] - low < height) & (np.linalg.norm(vel, axis=-1) < speed)


def licence_of(clip_id: str, convention: str | None) -> str:
    text = clip_id.lower()
    if "bandai" in text or convention == "bandai_namco":
        return LICENCES["bandai_namco"]
    if "cmu" in text or (convention or "").startswith("cmu"):
        return LICENCES["cmu"]
    return "unknown (the source's own terms)"


@dataclass
class _Item:
    clip_id: str
    source: str
    data: bytes | None = None   # the BVH's bytes (archive members), else read from `source`


def _clip_id(rel: str) -> str:
    rel = rel[:-4] if rel.lower().endswith(".bvh") else rel
    return rel.strip("/").replace("/", "__")


def _is_archive(path: Path) -> bool:
    return path.name.lower().endswith(_ARCHIVES)


def iter_corpus(inputs) -> list[tuple[str, Path, Path]]:
    """(kind, path, base) for each input in order: kind "file" or "archive", base the folder ids are relative
    to. Folders expand to their BVH files and archives (sorted); a missing input raises FileNotFoundError."""
    out = []
    for given in inputs:
        path = Path(given).expanduser()
        if not path.exists():
            raise FileNotFoundError(f"mocap input not found: {path}")
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file() and (p.suffix.lower() == ".bvh"
                                                                          or _is_archive(p)))
            if not found:
                raise FileNotFoundError(f"no .bvh files or tar archives under {path}")
            out += [("archive" if _is_archive(p) else "file", p, path) for p in found]
        elif _is_archive(path):
            out.append(("archive", path, path.parent))
        elif path.suffix.lower() == ".bvh":
            out.append(("file", path, path.parent))
        else:
            raise ValueError(f"{path}: not a .bvh file, a folder or a tar archive ({', '.join(_ARCHIVES)})")
    return out


def _items(inputs):
    """Every BVH of the inputs as an _Item, archives read member by member (streamed, in their order)."""
    for kind, path, base in iter_corpus(inputs):
        if kind == "file":
            rel = path.relative_to(base).as_posix() if path != base else path.name
            yield _Item(_clip_id(rel), str(path))
            continue
        stem = path.name
        for suffix in _ARCHIVES:
            if stem.lower().endswith(suffix):
                stem = stem[: -len(suffix)]
                break
        try:
            with tarfile.open(path, "r:*") as tar:
                for member in tar:
                    if not member.isfile() or not member.name.lower().endswith(".bvh"):
                        continue
                    fh = tar.extractfile(member)
                    if fh is None:
                        continue
                    yield _Item(_clip_id(f"{stem}/{member.name}"), f"{path}:{member.name}", fh.read())
        except (tarfile.TarError, OSError, EOFError) as err:
            yield _Item(_clip_id(stem), f"{path}: cannot read the archive: {err}", b"")  # reported as failed


def cache_key(data: bytes, config: CorpusConfig, model: BodyModel) -> str:
    settings = json.dumps({"version": FORMAT_VERSION, "retarget": asdict(config.retarget),
                           "contact": [config.contact_height, config.contact_speed],
                           "model": getattr(model.data, "name", "")}, sort_keys=True)
    return hashlib.sha1(data + settings.encode()).hexdigest()[:16]


def convert_clip(model: BodyModel, text: str, clip_id: str, source: str, config: CorpusConfig) -> dict:
    """One BVH's text -> the arrays stored for the clip (see the module docstring)."""
    from m3c.eval.retarget import detect_joint_map
    from m3c.io.bvh import parse_bvh

    bvh = parse_bvh(text, source)
    convention = detect_joint_map(bvh)
    # CMU's 3dsMax and MotionBuilder conversions start with an added T-pose frame.
    frames = slice(1, None) if convention in ("cmu_3dsmax", "cmu_motionbuilder") else None
    motion = fast_retarget(model, bvh, convention, config.retarget, frames)
    if motion.num_frames < config.min_frames:
        raise ValueError(f"{motion.num_frames} frames at {motion.fps:g} fps, fewer than {config.min_frames}")
    pose = motion.pose()
    if not np.all(np.isfinite(pose)) or not np.all(np.isfinite(motion.transl)):
        raise ValueError("the retargeted motion has NaN or infinite values")
    joints = model.joints(pose, motion.betas, motion.transl)
    contacts = foot_contacts(joints, motion.fps, config.contact_height, config.contact_speed)
    return {"pose": pose.astype(np.float32), "transl": motion.transl.astype(np.float32),
            "betas": motion.betas.astype(np.float32), "contacts": contacts,
            "fps": np.float32(motion.fps), "fit_error_mm": motion.fit_error_mm.astype(np.float32),
            "clip": np.array(clip_id), "source": np.array(source),
            "licence": np.array(licence_of(clip_id, convention)), "convention": np.array(convention),
            "scale": np.float64(motion.info["scale"]),
            "refined_frames": np.int64(motion.info["refined_frames"])}


def _work(args):
    """Worker: (clip_id, source, data, out_path, key, config, model_file) -> summary dict (never raises)."""
    clip_id, source, data, out_path, key, config, model = args
    start = time.perf_counter()
    try:
        if not data:
            raise ValueError("empty or unreadable file")
        arrays = convert_clip(_worker_model(model), data.decode("utf-8", errors="replace"), clip_id, source,
                              config)
        save_npz_atomic(out_path, key=np.array(key), **arrays)
        return {"clip": clip_id, "ok": True, "frames": len(arrays["pose"]), "source": source,
                "licence": str(arrays["licence"]), "fit_error_mm": float(arrays["fit_error_mm"].mean()),
                "refined_frames": int(arrays["refined_frames"]), "seconds": time.perf_counter() - start}
    except Exception as err:  # noqa: BLE001 - a bad file is reported and skipped, never the whole run lost
        return {"clip": clip_id, "ok": False, "source": source, "error": f"{type(err).__name__}: {err}",
                "seconds": time.perf_counter() - start}


_MODEL_CACHE: dict = {}


def _worker_model(model):
    """The body model itself, or (in a worker process) loaded once from its file."""
    if isinstance(model, BodyModel):
        return model
    if model not in _MODEL_CACHE:
        from m3c.body import default_body_model

        _MODEL_CACHE[model] = default_body_model(model or None)
    return _MODEL_CACHE[model]


def _init_worker():
    import os

    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass


def _cached(path: Path, key: str) -> dict | None:
    try:
        with np.load(path) as z:
            if str(z["key"]) != key:
                return None
            return {"clip": str(z["clip"]), "ok": True, "frames": len(z["pose"]), "source": str(z["source"]),
                    "licence": str(z["licence"]), "fit_error_mm": float(z["fit_error_mm"].mean()),
                    "refined_frames": int(z["refined_frames"]), "seconds": 0.0, "cached": True}
    except (OSError, KeyError, ValueError):
        return None


def build_corpus(inputs, out_dir: str | Path, model: BodyModel, config: CorpusConfig | None = None,
                 workers: int = 1, model_file: str = "", log=print, limit: int | None = None) -> dict:
    """Converts every BVH of `inputs` (files, folders, tar archives) into out_dir (layout: module docstring)
    and returns the index. workers > 1 retargets in that many processes (model_file: the body model they load;
    empty: the default open model)."""
    config = config or CorpusConfig()
    out_dir = Path(out_dir)
    clip_dir = out_dir / "clips"
    clip_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    results, excluded, seen = [], [], set()

    def jobs():
        for item in _items(inputs):
            name = item.clip_id.split("__")[-1]
            if name in config.exclude:
                excluded.append(item.clip_id)
                continue
            if item.clip_id in seen:
                results.append({"clip": item.clip_id, "ok": False, "source": item.source,
                                "error": "duplicate clip id (a file of the same path given twice)"})
                continue
            seen.add(item.clip_id)
            if limit is not None and len(seen) > limit:
                return
            data = item.data if item.data is not None else Path(item.source).read_bytes()
            key = cache_key(data, config, model)
            out_path = clip_dir / f"{item.clip_id}.npz"
            done = _cached(out_path, key) if out_path.is_file() else None
            if done is not None:
                yield done
                continue
            yield (item.clip_id, item.source, data, out_path, key, config,
                   model if workers <= 1 else model_file)

    def run_all():
        if workers <= 1:
            for job in jobs():
                yield job if isinstance(job, dict) else _work(job)
            return
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker) as pool:
            pending = []
            for job in jobs():
                if isinstance(job, dict):
                    pending.append(job)
                else:
                    pending.append(pool.apply_async(_work, (job,)))
                # Keep the queue short (memory) and the order fixed (determinism of index.json).
                while len(pending) > 4 * workers:
                    head = pending.pop(0)
                    yield head if isinstance(head, dict) else head.get()
            for head in pending:
                yield head if isinstance(head, dict) else head.get()

    frames_done = 0
    for k, res in enumerate(run_all(), start=1):
        results.append(res)
        elapsed = time.perf_counter() - start
        if res["ok"]:
            frames_done += res["frames"]
            what = (f"{res['frames']} frames, fit {res['fit_error_mm']:.1f} mm, {res['refined_frames']} "
                    "refined, "
                    + ("cached" if res.get("cached") else f"{res['seconds']:.2f} s"))
        else:
            what = f"FAILED: {res['error']}"
        if log:
            log(f"[{k}] {res['clip']}: {what} | {frames_done} frames in {elapsed:.0f} s")

    ok = [r for r in results if r["ok"]]
    split = {"train": sorted(r["clip"] for r in ok if not held_out(r["clip"], config.held_out_percent)),
             "held_out": sorted(r["clip"] for r in ok if held_out(r["clip"], config.held_out_percent))}
    index = {"format_version": FORMAT_VERSION, "body_model": getattr(model.data, "name", ""),
             "fps": config.retarget.fps, "held_out_percent": config.held_out_percent,
             "contact_joints": list(CONTACT_NAMES), "excluded_benchmark_clips": sorted(excluded),
             "clips": {r["clip"]: {k: r[k] for k in ("frames", "source", "licence", "fit_error_mm",
                                                     "refined_frames")}
                       | {"split": "held_out" if r["clip"] in split["held_out"] else "train"} for r in ok},
             "failed": {r["clip"]: {"source": r["source"], "error": r["error"]}
                        for r in results if not r["ok"]},
             "frames": int(sum(r["frames"] for r in ok)), "seconds": time.perf_counter() - start}
    with atomic_path(out_dir / "index.json") as tmp:
        tmp.write_text(json.dumps(index, indent=1) + "\n")
    with atomic_path(out_dir / "split.json") as tmp:
        tmp.write_text(json.dumps(split, indent=1) + "\n")
    return index


def load_corpus(out_dir: str | Path, split: str | None = None) -> list[dict]:
    """The clips of a corpus folder (all, or one split: "train" / "held_out") as dicts of arrays."""
    out_dir = Path(out_dir)
    split_file = out_dir / "split.json"
    if not split_file.is_file():
        raise FileNotFoundError(f"{out_dir}: no split.json; is it a folder written by `m3c data mocap`?")
    splits = json.loads(split_file.read_text())
    if split is not None and split not in splits:
        raise ValueError(f"unknown split {split!r}; choose from {sorted(splits)}")
    names = splits[split] if split else sorted(splits["train"] + splits["held_out"])
    clips = []
    for name in names:
        with np.load(out_dir / "clips" / f"{name}.npz") as z:
            clips.append({k: z[k] for k in z.files})
    return clips


# What the corpus covers: the share of frames in poses a video may show that locomotion-heavy mocap lacks.
COVERAGE_TESTS = {
    "pelvis_below_0.6m": "sitting, crouching, kneeling or lying: the pelvis under 0.6 m above the ground",
    "knee_over_90deg": "either knee bent more than 90 degrees",
    "trunk_tilt_over_45deg": "the pelvis's up axis more than 45 degrees from vertical (bending over, lying)",
    "both_feet_off_ground": "no foot contact (jumps and the flight phase of running)",
    "arm_above_shoulder": "a wrist above its shoulder",
}


def corpus_coverage(clips, model: BodyModel) -> dict:
    """Share of frames (0-1) of the clips (dicts of a corpus's arrays) meeting each COVERAGE_TESTS test."""
    from scipy.spatial.transform import Rotation

    counts = dict.fromkeys(COVERAGE_TESTS, 0)
    total = 0
    for clip in clips:
        pose, transl, betas = (np.asarray(clip[k], dtype=np.float64) for k in ("pose", "transl", "betas"))
        joints = model.joints(pose, betas, transl)
        knee = np.linalg.norm(pose[:, [4, 5]], axis=-1).max(axis=1)
        up = Rotation.from_rotvec(pose[:, 0]).as_matrix()[:, :, 1]
        counts["pelvis_below_0.6m"] += int(np.count_nonzero(joints[:, 0, 1] < 0.6))
        counts["knee_over_90deg"] += int(np.count_nonzero(knee > np.pi / 2))
        counts["trunk_tilt_over_45deg"] += int(np.count_nonzero(up[:, 1] < np.cos(np.pi / 4)))
        counts["both_feet_off_ground"] += int(np.count_nonzero(~np.asarray(clip["contacts"]).any(axis=1)))
        counts["arm_above_shoulder"] += int(np.count_nonzero((joints[:, [20, 21], 1]
                                                              > joints[:, [16, 17], 1]).any(axis=1)))
        total += len(pose)
    return {"frames": total, **{k: v / max(total, 1) for k, v in counts.items()}}
