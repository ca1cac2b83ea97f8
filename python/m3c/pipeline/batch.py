"""Many videos through one pipeline: `m3c batch`. Each video runs as `m3c run` would, into OUT/<name>/ with its own
node cache, so a re-run skips finished work and resumes unfinished videos.

With Ray installed (pip install 'm3c[batch]') every video is one Ray task (a local Ray instance by default, a
cluster with `address`); Ray does the scheduling, resource accounting and transport. Without Ray the videos run one
after another in this process. A video that fails is recorded with its error and the others go on; the outcome of
every video is written to OUT/batch_summary.json (atomically) and printed as a table.
"""

from __future__ import annotations

import json
import logging
import os
import time
import traceback
from collections import defaultdict
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from m3c.io import atomic_path
from m3c.pipeline.config import PipelineConfig
from m3c.pipeline.graph import Graph
from m3c.pipeline.node import Needs
from m3c.pipeline.progress import Progress

LOG = logging.getLogger("m3c.batch")

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".3gp", ".ts",
                  ".mts", ".m2ts")
LIST_SUFFIXES = (".txt", ".lst")
SUMMARY = "batch_summary.json"


@dataclass
class VideoOutcome:
    video: str  # the input file, resolved
    name: str  # the result folder under OUT
    status: str  # "done" or "failed"
    seconds: float = 0.0
    nodes_ran: int = 0
    nodes_cached: int = 0
    error: str = ""  # "<ExceptionType>: message" for a failed video
    worker: str = ""  # host:pid that ran it


def collect_videos(inputs: list[str | Path]) -> list[Path]:
    """Video files from `inputs`: video files, folders (their video files, recursively, sorted) and text files
    listing one video or folder per line (blank lines and # comments skipped; relative paths are relative to the
    list's folder). Each file once, in the order given. ValueError naming a missing or unusable input."""
    videos: list[Path] = []
    seen: set[Path] = set()

    def add(path: Path, listed_in: Path | None) -> None:
        where = f" (listed in {listed_in})" if listed_in else ""
        if not path.exists():
            raise ValueError(f"batch input not found: {path}{where}")
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES
                           and not p.name.startswith("."))
            if not found:
                raise ValueError(f"folder {path}{where} holds no video files ({', '.join(VIDEO_SUFFIXES)})")
            for p in found:
                add(p, listed_in)
        elif path.suffix.lower() in LIST_SUFFIXES:
            if listed_in is not None:
                raise ValueError(f"{path}: a list of videos may not name another list{where}")
            for line in path.read_text().splitlines():
                entry = line.split("#", 1)[0].strip()
                if entry:
                    item = Path(entry).expanduser()
                    add(item if item.is_absolute() else path.parent / item, path)
        else:
            resolved = path.resolve()
            if resolved not in seen:  # the same file named twice runs once
                seen.add(resolved)
                videos.append(resolved)

    for item in inputs:
        add(Path(item).expanduser(), None)
    if not videos:
        raise ValueError("no videos to process: give video files, folders of videos, or .txt lists of them")
    return videos


def result_names(videos: list[Path]) -> dict[Path, str]:
    """The result folder name of each video: its stem (file name without extension), as `m3c run --out OUT/<stem>`.

    Videos whose stems collide get the folders that tell them apart, from their common parent down, joined by
    "__" (a/clip.mp4, b/clip.mp4 -> a__clip, b__clip); files that differ only in their extension keep it
    (clip.mp4, clip.mov -> clip_mp4, clip_mov). The names depend only on the colliding files, so a batch run
    again over the same inputs finds its folders (and caches) again."""
    groups: dict[str, list[Path]] = defaultdict(list)
    for video in videos:
        groups[video.stem].append(video)
    names: dict[Path, str] = {}
    for stem, group in groups.items():
        if len(group) == 1:
            names[group[0]] = stem
            continue
        common = Path(os.path.commonpath([str(v.parent) for v in group]))
        for video in group:
            parts = video.relative_to(common).with_suffix("").parts
            names[video] = "__".join(parts)
        if len({names[v] for v in group}) < len(group):
            for video in group:
                parts = video.relative_to(common).parts
                names[video] = "__".join(parts).replace(".", "_")
    taken = defaultdict(list)
    for video, name in names.items():
        taken[name].append(video)
    clashes = {name: vs for name, vs in taken.items() if len(vs) > 1}
    if clashes:  # a disambiguated name equals another video's stem: name the files so the user can rename one
        name, vs = next(iter(clashes.items()))
        raise ValueError(f"videos {', '.join(map(str, vs))} would share the result folder {name!r}; rename one")
    return names


def run_video(config: PipelineConfig, video: str | Path, out_dir: str | Path) -> VideoOutcome:
    """Runs the pipeline on one video into out_dir (as `m3c run VIDEO --out out_dir`); never raises for a failure
    of the video: the error goes into the outcome."""
    import socket

    from m3c.pipeline.runner import Runner

    video, out_dir = Path(video), Path(out_dir)
    outcome = VideoOutcome(str(video), out_dir.name, "failed", worker=f"{socket.gethostname()}:{os.getpid()}")
    start = time.perf_counter()
    try:
        report = Runner(config, out_dir, {"video": video}, show_progress=False).run()
        outcome.status = "done"
        outcome.nodes_ran = len(report.ran())
        outcome.nodes_cached = sum(1 for r in report.records if r.status == "cached")
    except Exception as err:  # noqa: BLE001 - one video's failure (any kind) must not stop the batch
        outcome.error = f"{type(err).__name__}: {err}"
        LOG.debug("%s failed:\n%s", video, traceback.format_exc())
    outcome.seconds = round(time.perf_counter() - start, 3)
    return outcome


@dataclass
class BatchReport:
    out_dir: str
    engine: str  # "ray (<address>)" or "sequential"
    outcomes: list[VideoOutcome]
    seconds: float

    @property
    def failed(self) -> list[VideoOutcome]:
        return [o for o in self.outcomes if o.status != "done"]

    def table(self) -> str:
        width = max([len(o.name) for o in self.outcomes] + [5])
        lines = [f"  {'video':<{width}}  {'status':<6}  {'seconds':>8}  {'ran':>3}  {'cached':>6}  error"]
        for o in self.outcomes:
            lines.append(f"  {o.name:<{width}}  {o.status:<6}  {o.seconds:8.1f}  {o.nodes_ran:3d}  "
                         f"{o.nodes_cached:6d}  {o.error.splitlines()[0] if o.error else ''}")
        lines.append(f"  {len(self.outcomes) - len(self.failed)} of {len(self.outcomes)} video(s) done, "
                     f"{len(self.failed)} failed, {self.seconds:.1f} s in all ({self.engine})")
        return "\n".join(lines)

    def write(self, path: Path) -> None:
        data = {"out_dir": self.out_dir, "engine": self.engine, "seconds": round(self.seconds, 3),
                "done": len(self.outcomes) - len(self.failed), "failed": len(self.failed),
                "videos": [asdict(o) for o in self.outcomes]}
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(data, indent=1) + "\n")


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


# Ray takes a node's address from the interface that routes outwards and serves its GCS, raylet, object store and
# workers on it, so a single-machine batch would be reachable from the network (Ray's job API was
# CVE-2023-48022). With this variable off (as Ray runs on Windows and macOS), the node's address is the loopback
# one and every server listens there. Read by ray._private.ray_constants when ray is imported, and inherited by the
# raylet and its workers from the environment ray.init starts them in.
_RAY_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def start_local_ray(**init_kwargs) -> None:
    """ray.init of a new Ray on this machine alone: every server on 127.0.0.1, no dashboard."""
    import ray
    from ray._private import ray_constants

    previous = os.environ.get(_RAY_LOOPBACK_ENV)
    os.environ[_RAY_LOOPBACK_ENV] = "0"
    enabled, ray_constants.ENABLE_RAY_CLUSTER = ray_constants.ENABLE_RAY_CLUSTER, False  # ray imported before
    try:
        ray.init(address="local", include_dashboard=False, _node_ip_address="127.0.0.1", **init_kwargs)
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = enabled
        if previous is None:
            os.environ.pop(_RAY_LOOPBACK_ENV, None)
        else:
            os.environ[_RAY_LOOPBACK_ENV] = previous


def video_needs(config: PipelineConfig) -> Needs:
    """What one video's run needs: its nodes run one after another, so the most cores and the most memory that any
    node of the pipeline needs (each node's Needs: its type's, or its config entry's `needs`)."""
    needs = [node.needs for node in Graph.from_config(config).nodes.values()]
    return Needs(max(n.cpus for n in needs), max(n.memory_gb for n in needs))


def run_batch(config: PipelineConfig, videos: list[Path], out_dir: str | Path, *, use_ray: bool = True,
              address: str | None = None, cpus_per_video: float | None = None,
              memory_per_video_gb: float | None = None, show_progress: bool = True,
              progress_stream=None, setup: Callable[[], None] | None = None) -> BatchReport:
    """Every video of `videos` through `config` into out_dir/<result_names()[video]>/; the summary is written to
    out_dir/batch_summary.json. use_ray: run on Ray when it is installed (address: a cluster's address, None =
    start a local instance; each video asks Ray for cpus_per_video CPUs, memory_per_video_gb of memory and, with
    settings.device on CUDA, one GPU; None: video_needs(config), what the pipeline's nodes declare). setup: called
    once in this process and in every Ray task before its video runs, to register the node types the config uses
    (the m3c command passes m3c.nodes.register_builtin_nodes); a module-level function, so Ray ships it by name."""
    if setup is not None:
        setup()
    needs = video_needs(config)
    cpus_per_video = needs.cpus if cpus_per_video is None else cpus_per_video
    memory_per_video_gb = needs.memory_gb if memory_per_video_gb is None else memory_per_video_gb
    out_dir = Path(out_dir)
    names = result_names(videos)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress("batch: videos", len(videos), LOG, stream=progress_stream, enabled=show_progress)
    start = time.perf_counter()
    if use_ray and not ray_available():
        if address:
            raise ImportError("--address needs Ray: pip install 'm3c[batch]'")
        LOG.warning("Ray is not installed (pip install 'm3c[batch]'): running the %d video(s) one after another "
                    "in this process", len(videos))
        use_ray = False
    outcomes: dict[Path, VideoOutcome] = {}

    def finished(video: Path, outcome: VideoOutcome) -> None:
        outcomes[video] = outcome
        state = (f"done in {outcome.seconds:.1f} s ({outcome.nodes_ran} node(s) ran, {outcome.nodes_cached} cached)"
                 if outcome.status == "done" else f"FAILED after {outcome.seconds:.1f} s: {outcome.error}")
        LOG.info("[%d/%d] %s: %s", len(outcomes), len(videos), names[video], state)
        progress.update()

    if use_ray:
        engine = _run_on_ray(config, videos, names, out_dir, address, cpus_per_video, memory_per_video_gb, finished,
                             setup)
    else:
        engine = "sequential"
        for video in videos:
            finished(video, run_video(config, video, out_dir / names[video]))
    progress.close()
    report = BatchReport(str(out_dir), engine, [outcomes[v] for v in videos], time.perf_counter() - start)
    report.write(out_dir / SUMMARY)
    return report


def _run_video_after(setup: Callable[[], None] | None, config: PipelineConfig, video: str, out_dir: str
                     ) -> VideoOutcome:
    """A Ray task: a worker process registers the node types (setup) before it runs the video."""
    if setup is not None:
        setup()
    return run_video(config, video, out_dir)


def _run_on_ray(config, videos, names, out_dir, address, cpus_per_video, memory_per_video_gb, finished,
                setup) -> str:
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        # address None: a new local instance, never one Ray finds by itself (a stale record of a stopped cluster
        # makes ray.init() wait for it for ever); "auto" joins the one running here. The m3c of this process must be
        # importable on the workers (installed there, or on PYTHONPATH, which local workers inherit).
        if address:
            ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
        else:
            start_local_ray(logging_level=logging.WARNING, log_to_driver=False)
    try:
        resources = {"num_cpus": cpus_per_video, "memory": int(memory_per_video_gb * 2**30)}
        if config.settings.device.startswith("cuda"):
            resources["num_gpus"] = 1
        _check_feasible(ray, resources, address)
        # max_retries=0: a video whose worker died is reported, not silently run again (re-running the batch
        # resumes it from its cache).
        task = ray.remote(max_retries=0, **resources)(_run_video_after)
        config_ref = ray.put(config)
        pending = {task.remote(setup, config_ref, str(v), str(out_dir / names[v])): v for v in videos}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                video = pending.pop(ref)
                try:
                    outcome = ray.get(ref)
                except Exception as err:  # noqa: BLE001 - the worker process died (killed, out of memory)
                    outcome = VideoOutcome(str(video), names[video], "failed",
                                           error=f"{type(err).__name__}: {str(err).splitlines()[0]}")
                finished(video, outcome)
        return (f"ray at {ray.get_runtime_context().gcs_address}, {int(ray.cluster_resources().get('CPU', 0))} "
                f"CPU(s); {cpus_per_video:g} CPU(s) and {memory_per_video_gb:g} GB per video")
    finally:
        if started_here:
            ray.shutdown()


def _check_feasible(ray, resources: dict, address: str | None) -> None:
    """ValueError unless some Ray node can hold one video's request (Ray would otherwise wait for ever)."""
    wanted = {"CPU": resources["num_cpus"], "memory": resources["memory"], "GPU": resources.get("num_gpus", 0)}
    nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
    if any(all(node.get(k, 0) >= v for k, v in wanted.items()) for node in nodes):
        return
    largest = max(nodes, key=lambda n: (n.get("CPU", 0), n.get("memory", 0)), default={})
    raise ValueError(f"no Ray node of {'cluster ' + address if address else 'this Ray instance'} can run one "
                     f"video: each asks for {wanted['CPU']:g} CPU(s), {wanted['memory'] / 2**30:.1f} GB"
                     f"{', 1 GPU' if wanted['GPU'] else ''}; the largest node has {largest.get('CPU', 0):g} CPU(s), "
                     f"{largest.get('memory', 0) / 2**30:.1f} GB, {largest.get('GPU', 0):g} GPU(s). Lower "
                     "--cpus-per-video / --memory-per-video")
