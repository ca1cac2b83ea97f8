"""Runs the execution graph: keys, cache reuse, model load/unload around each node, timing, logging, publishing.

A run computes every node's cache key first (keys depend only on configs, code versions, settings, sources and
upstream keys, never on outputs), runs the nodes whose key has no complete cache entry in topological order, and
publishes the files of result nodes into the output folder. Outputs handed downstream are always read back from
the committed cache entry, so a node sees the same values whether its inputs were computed now or resumed.
"""

from __future__ import annotations

import contextlib
import fcntl
import gc
import logging
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import m3c
from m3c.io import atomic_path
from m3c.io import manifest as manifest_io
from m3c.pipeline.cache import Cache, digest, file_digest
from m3c.pipeline.config import PipelineConfig, Settings, check_settings
from m3c.pipeline.finite import check_outputs
from m3c.pipeline.graph import Graph
from m3c.pipeline.node import (
    ComponentUnavailable,
    FileRef,
    InputError,
    Node,
    PipelineError,
    config_to_dict,
    setting_loader,
)
from m3c.pipeline.progress import Progress

LOG = logging.getLogger("m3c.pipeline")


class PipelineUnavailable(PipelineError):
    """One or more nodes cannot run in this installation; `problems` holds one ComponentUnavailable each."""

    def __init__(self, problems: list[ComponentUnavailable]):
        self.problems = problems
        lines = "\n".join(f"  - {p}" for p in problems)
        super().__init__(f"{len(problems)} node(s) cannot run:\n{lines}")


class RunContext:
    """What a node sees of the run: settings, sources, its work folder, progress, logging, shared resources."""

    def __init__(self, runner: "Runner", node: str, work_dir: Path | None = None):
        self._runner = runner
        self.node = node
        self.work_dir = work_dir
        self.settings: Settings = runner.config.settings
        self.out_dir: Path = runner.out_dir
        self.log = logging.getLogger(f"m3c.nodes.{node}")

    @property
    def device(self) -> str:
        return self.settings.device

    def source(self, name: str) -> Path:
        try:
            return self._runner.sources[name]
        except KeyError:
            raise InputError(f"node {self.node!r} reads the run source {name!r}, which this run was not given") \
                from None

    def progress(self, desc: str, total: int | None) -> Progress:
        return Progress(f"{self.node}: {desc}", total, self.log, stream=self._runner.progress_stream,
                        enabled=self._runner.show_progress)

    def work_path(self, name: str) -> Path:
        """Where to write an output file `name`; return FileRef(name) for it among the outputs."""
        if self.work_dir is None:
            raise PipelineError(f"node {self.node!r} has no work folder outside run()")
        path = self.work_dir / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def loaded(self, setting: str):
        """What the setting names (e.g. "body_model": the configured body model), loaded once per run by the
        setting's registered loader (m3c.pipeline.node.register_setting_loader)."""
        return self._runner.loaded(setting)

    def upstream_nodes(self) -> dict[str, dict]:
        """Type and config of every node this node depends on (they are part of its cache key through its
        inputs' keys), for recording which backends produced a result."""
        graph = self._runner.graph
        names = graph.upstream([self.node]) - {self.node}
        return {n: {"type": graph.nodes[n].type_name, "config": config_to_dict(graph.nodes[n].config)}
                for n in graph.order if n in names}

    def models_dir(self) -> Path | None:
        """The checkpoint folder: settings.models_dir, else $M3C_MODELS, else None."""
        folder = self.settings.models_dir or os.environ.get("M3C_MODELS")
        return Path(folder).expanduser() if folder else None


@dataclass
class NodeRecord:
    name: str
    type: str
    level: str
    key: str
    status: str  # "ran", "cached", "failed", "skipped"
    seconds: float = 0.0
    message: str = ""


@dataclass
class RunReport:
    out_dir: str
    records: list[NodeRecord] = field(default_factory=list)
    published: dict[str, str] = field(default_factory=dict)  # file name -> node

    def status(self) -> dict[str, str]:
        return {r.name: r.status for r in self.records}

    def ran(self) -> list[str]:
        return [r.name for r in self.records if r.status == "ran"]

    def summary(self) -> str:
        width = max((len(r.name) for r in self.records), default=4)
        lines = [f"  {r.name:<{width}}  {r.status:<7} {r.seconds:8.2f} s  {r.key}" for r in self.records]
        total = sum(r.seconds for r in self.records)
        return "\n".join(lines + [f"  {'total':<{width}}  {'':<7} {total:8.2f} s"])


class Runner:
    """Runs a PipelineConfig into `out_dir` (results there, cache in out_dir/cache).

    sources: run inputs by name (e.g. {"video": path}); nodes declare which they read.
    """

    def __init__(self, config: PipelineConfig, out_dir: str | Path, sources: dict[str, str | Path] | None = None,
                 show_progress: bool = True, progress_stream=None):
        self.config = config
        self.graph = Graph.from_config(config)
        self.out_dir = Path(out_dir)
        self.cache = Cache(self.out_dir / "cache")
        self.sources = {k: Path(v) for k, v in (sources or {}).items()}
        self.show_progress = show_progress
        self.progress_stream = progress_stream if progress_stream is not None else sys.stderr
        self._loaded: dict[str, Any] = {}  # setting -> what its loader built, once per run
        self._publishing: dict = {}  # the "running" manifest of this run, once written
        self._setting_digests: dict[str, Any] = {}

    # Keys ---------------------------------------------------------------------------------------------------
    def setting_fingerprint(self, name: str) -> Any:
        if name not in self._setting_digests:
            settings = self.config.settings
            if not hasattr(settings, name):
                raise PipelineError(f"unknown setting {name!r}")
            value = getattr(settings, name)
            loader = setting_loader(name)
            if loader is not None:
                value = loader.fingerprint(value)
            elif name == "models_dir":
                folder = value or os.environ.get("M3C_MODELS")
                value = str(Path(folder).expanduser().resolve()) if folder else None
            self._setting_digests[name] = value
        return self._setting_digests[name]

    def source_fingerprint(self, name: str) -> str:
        path = self.sources.get(name)
        if path is None:
            raise InputError(f"this pipeline reads the source {name!r}, but the run was not given one")
        if path.is_dir():
            raise InputError(f"{name} must be a file, but {path} is a folder")
        if not path.is_file():
            raise InputError(f"{name} file not found: {path}")
        return file_digest(path)

    def keys(self, names: list[str]) -> dict[str, str]:
        keys: dict[str, str] = {}
        for name in names:
            node = self.graph.nodes[name]
            ctx = RunContext(self, name)
            material = {
                "type": node.type_name,
                "code": node.code_version(),
                "m3c": m3c.__version__,
                "config": node.key_config(ctx),
                "settings": {s: self.setting_fingerprint(s) for s in node.settings},
                "sources": {s: self.source_fingerprint(s) for s in node.sources},
                "inputs": {e.slot: f"{keys[e.source]}.{e.output}" for e in self.graph.inputs_of(name)},
            }
            keys[name] = digest(material)
        return keys

    def loaded(self, setting: str):
        if setting not in self._loaded:
            loader = setting_loader(setting)
            if loader is None:
                raise PipelineError(f"the setting {setting!r} has no loader registered; the program that builds the "
                                    "graph registers it (m3c.nodes.register_builtin_nodes() for M3C's nodes)")
            self._loaded[setting] = loader.load(getattr(self.config.settings, setting))
        return self._loaded[setting]

    # Running ------------------------------------------------------------------------------------------------
    def plan(self, targets: list[str] | None = None) -> list[tuple[str, str, bool]]:
        """(node, key, cached) in execution order for the nodes `targets` need (default: all)."""
        order = self._order(targets)
        keys = self.keys(order)
        return [(n, keys[n], self.cache.has(n, keys[n])) for n in order]

    def _order(self, targets: list[str] | None) -> list[str]:
        if targets is None:
            return list(self.graph.order)
        unknown = set(targets) - set(self.graph.nodes)
        if unknown:
            raise PipelineError(f"unknown node(s) {sorted(unknown)}; nodes: {list(self.graph.order)}")
        needed = self.graph.upstream(targets)
        return [n for n in self.graph.order if n in needed]

    def run(self, targets: list[str] | None = None) -> RunReport:
        try:
            check_settings(self.config.settings)
            plan = self.plan(targets)
            to_run = [n for n, _, cached in plan if not cached]
            problems = []
            for name in to_run:
                try:
                    self.graph.nodes[name].check(RunContext(self, name))
                except ComponentUnavailable as err:
                    problems.append(err)
            if problems:
                raise PipelineUnavailable(problems)
        except (PipelineError, ValueError, OSError) as err:
            manifest_io.mark_failed(self.out_dir, err)  # an earlier run's results are not this configuration's
            raise

        created = not self.out_dir.exists()
        report = RunReport(str(self.out_dir))
        try:
            with self._lock():
                stale = self.cache.remove_stale_temporaries() + self._remove_stale_files()
                if stale:
                    LOG.info("removed %d unfinished file(s) or cache entr%s of an interrupted run", stale,
                             "y" if stale == 1 else "ies")
                marked = self._mark_running(plan)
                try:
                    self._execute(plan, report)
                except BaseException as err:
                    if marked:
                        self._mark_failed(err)
                    raise
        except BaseException:
            if created and not any(r.status == "ran" for r in report.records):
                shutil.rmtree(self.out_dir, ignore_errors=True)  # nothing worth keeping: leave no trace
            raise
        finally:
            if self.out_dir.exists():
                self._write_report(report)
        return report

    # Publishing: the files of one run appear together, the manifest written last (m3c.io.manifest) -------------
    def _planned_files(self, plan: list[tuple[str, str, bool]]) -> dict[str, dict]:
        return {filename: {"node": name, "key": key} for name, key, _ in plan
                for filename in self.graph.nodes[name].publish.values()}

    def _mark_running(self, plan: list[tuple[str, str, bool]]) -> bool:
        """Before a run that publishes files, the manifest says "running" (and names the earlier run), so the old
        files never look current meanwhile; _publish_all writes the complete one last."""
        planned = self._planned_files(plan)
        if not planned:
            return False
        self._publishing = manifest_io.running_manifest(self.out_dir, planned, os.getpid())
        self.out_dir.mkdir(parents=True, exist_ok=True)
        manifest_io.write_manifest(self.out_dir, self._publishing)
        return True

    def _mark_failed(self, err: BaseException) -> None:
        with contextlib.suppress(OSError):
            manifest_io.write_manifest(self.out_dir, manifest_io.failed_manifest(self._publishing, err))

    def _publish_all(self, pending: dict[str, tuple[str, str, Path]], report: RunReport) -> None:
        """Links every file into a staging folder, renames them into place, removes the files of earlier runs
        that this run does not vouch for, and writes the manifest last."""
        if not pending:
            return
        staging = self.out_dir / f".publish-{os.getpid()}"
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True)
        files = {}
        for filename, (node, key, source) in pending.items():
            target = staging / filename
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(source, target)  # same bytes, no copy
            except OSError:
                shutil.copyfile(source, target)
            files[filename] = manifest_io.file_entry(target, node, key)
        for filename in pending:
            (self.out_dir / filename).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / filename, self.out_dir / filename)
            report.published[filename] = pending[filename][0]
        # Files of the earlier run this run did not write (e.g. it ran --until results): kept when the node that
        # wrote them has the same key now (they are this configuration's), removed otherwise.
        previous = (self._publishing.get("previous") or {}).get("files", {})
        current = self._current_keys() if set(previous) - set(files) else {}
        for filename in sorted(set(previous) - set(files)):
            entry, path = previous[filename], self.out_dir / filename
            if path.is_file() and entry.get("node") in current and current[entry["node"]] == entry.get("key") \
                    and manifest_io.file_entry(path, entry["node"], entry["key"]) == entry:
                files[filename] = entry
            elif filename != manifest_io.MANIFEST:
                path.unlink(missing_ok=True)
                LOG.info("removed %s of an earlier run with other settings (this run does not write it)", filename)
        shutil.rmtree(staging, ignore_errors=True)
        manifest_io.write_manifest(self.out_dir, {"status": "complete", "run_key": manifest_io.run_key(files),
                                                  "m3c_version": m3c.__version__, "files": files})

    def _remove_stale_files(self) -> int:
        """Temporary files a killed run left beside the files written atomically here (atomic_path names them
        .<name>.<random><suffix>): published results, the run report, pictures. Call with the run lock."""
        names = {name for node in self.graph.nodes.values() for name in node.publish.values()}
        stale = [p for name in sorted(names) for p in self.out_dir.glob(f".{name}.*")]
        stale += list(self.cache.root.glob(".last_run.json.*")) + list(self.out_dir.glob(f".{manifest_io.MANIFEST}.*"))
        for path in stale:
            path.unlink(missing_ok=True)
        folders = list((self.out_dir / "viz").glob(".tmp-*")) + list(self.out_dir.glob(".publish-*"))
        for folder in folders:
            shutil.rmtree(folder, ignore_errors=True)
        return len(stale) + len(folders)

    @contextlib.contextmanager
    def _lock(self):
        self.cache.root.mkdir(parents=True, exist_ok=True)
        with open(self.cache.root / ".lock", "w") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise PipelineError(f"another m3c run is writing to {self.out_dir}; wait for it or choose another "
                                    "--out folder") from None
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def _execute(self, plan: list[tuple[str, str, bool]], report: RunReport) -> None:
        keys = {n: k for n, k, _ in plan}
        names = [n for n, _, _ in plan]
        to_run = {n for n, _, cached in plan if not cached}
        # How many nodes still to run read each node's outputs: values are dropped from memory at zero.
        consumers = {n: sum(1 for e in self.graph.edges if e.source == n and e.target in to_run) for n in names}
        values: dict[str, dict[str, Any]] = {}

        def outputs_of(name: str) -> dict[str, Any]:
            if name not in values:
                values[name] = self.cache.load(name, keys[name])
            return values[name]

        total = len(plan)
        pending: dict[str, tuple[str, str, Path]] = {}  # file name -> (node, key, committed file)
        for index, (name, key, cached) in enumerate(plan, 1):
            node = self.graph.nodes[name]
            record = NodeRecord(name, node.type_name, node.level, key, "cached" if cached else "running")
            report.records.append(record)
            if cached:
                LOG.info("[%d/%d] %s: cached (%s)", index, total, name, key)
            else:
                inputs = self._gather_inputs(name, outputs_of)
                LOG.info("[%d/%d] %s: running", index, total, name)
                start = time.perf_counter()
                try:
                    self._run_node(node, key, inputs, keys)
                except BaseException as err:
                    record.status, record.seconds = "failed", time.perf_counter() - start
                    record.message = str(err)
                    raise
                record.status, record.seconds = "ran", time.perf_counter() - start
                LOG.info("[%d/%d] %s: done in %.2f s", index, total, name, record.seconds)
                for e in self.graph.inputs_of(name):
                    consumers[e.source] -= 1
                    if consumers[e.source] <= 0:
                        values.pop(e.source, None)
                release_heap()  # what the node held while it ran, back to the system
                if self.config.settings.visualize:
                    self._visualize(node, key, inputs, outputs_of(name))
            if node.publish:
                pending.update(self._files_to_publish(node, key, outputs_of(name)))
            if consumers.get(name, 0) <= 0:
                values.pop(name, None)
        self._publish_all(pending, report)

    def _gather_inputs(self, name: str, outputs_of) -> dict[str, Any]:
        node = self.graph.nodes[name]
        inputs: dict[str, Any] = {slot: None for slot in node.inputs}
        for e in self.graph.inputs_of(name):
            inputs[e.slot] = outputs_of(e.source)[e.output]
        return inputs

    def _run_node(self, node: Node, key: str, inputs: dict[str, Any], keys: dict[str, str]) -> None:
        writer = self.cache.writer(node.name, key)
        ctx = RunContext(self, node.name, writer.files_dir)
        start = time.perf_counter()
        try:
            node.load(ctx)
            try:
                outputs = node.run(ctx, inputs)
            finally:
                node.unload()
                if type(node).load is not Node.load:  # it held models: reclaim them now
                    _free_memory()
            if not isinstance(outputs, dict) or set(outputs) != set(node.outputs):
                got = sorted(outputs) if isinstance(outputs, dict) else type(outputs).__name__
                raise PipelineError(f"node {node.name!r} ({node.type_name}) must return its outputs "
                                    f"{list(node.outputs)}, returned {got}")
            outputs = check_outputs(node.name, node.type_name, outputs, node.nonfinite_outputs, ctx.log)
            meta = {"node": node.name, "type": node.type_name, "key": key, "code": node.code_version(),
                    "config": node.key_config(ctx), "m3c": m3c.__version__,
                    "inputs": {e.slot: f"{e.source}.{e.output}@{keys[e.source]}"
                               for e in self.graph.inputs_of(node.name)},
                    "seconds": round(time.perf_counter() - start, 3)}
            writer.commit({k: outputs[k] for k in node.outputs}, meta, node.name)
        except BaseException:
            writer.discard()
            raise

    def _current_keys(self) -> dict[str, str]:
        """Every node's key under this configuration (empty when some node's key cannot be computed here)."""
        try:
            return self.keys(list(self.graph.order))
        except PipelineError:
            return {}

    @staticmethod
    def _files_to_publish(node: Node, key: str, outputs: dict[str, Any]) -> dict[str, tuple[str, str, Path]]:
        files = {}
        for output, filename in node.publish.items():
            ref = outputs[output]
            if not isinstance(ref, FileRef):
                raise PipelineError(f"node {node.name!r}: published output {output!r} is not a file")
            files[filename] = (node.name, key, Path(ref.path))
        return files

    def _visualize(self, node: Node, key: str, inputs: dict[str, Any], outputs: dict[str, Any]) -> None:
        folder = self.out_dir / "viz" / node.name
        tmp = folder.parent / f".tmp-{node.name}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        files = node.visualize(RunContext(self, node.name), inputs, outputs, tmp)
        if not files:
            shutil.rmtree(tmp)
            return
        shutil.rmtree(folder, ignore_errors=True)
        os.rename(tmp, folder)
        LOG.info("%s: pictures in %s", node.name, folder)

    def _write_report(self, report: RunReport) -> None:
        import json

        path = self.cache.root / "last_run.json"
        with contextlib.suppress(OSError), atomic_path(path) as tmp:
            tmp.write_text(json.dumps(asdict(report), indent=1) + "\n")


def release_heap() -> bool:
    """Hands the heap memory freed so far back to the operating system (glibc's malloc_trim); True when it could.
    glibc keeps freed blocks for reuse, and after a node that peaked at gigabytes it keeps them for good (large
    numpy arrays move from mmap to the heap once big ones have been freed): without this the process would stay at
    that node's peak for the rest of the run, and a batch worker for the rest of the batch."""
    global _LIBC
    if _LIBC is None:
        import ctypes
        import ctypes.util

        name = ctypes.util.find_library("c")
        try:
            _LIBC = ctypes.CDLL(name) if name else False
        except OSError:
            _LIBC = False
    if not _LIBC or not hasattr(_LIBC, "malloc_trim"):  # not glibc (musl, macOS): nothing to do
        return False
    _LIBC.malloc_trim(0)
    return True


_LIBC = None


def _free_memory() -> None:
    """After a node's unload: collect its models now, and hand cached GPU blocks back to the driver."""
    gc.collect()
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available():
        torch.cuda.empty_cache()


def run_pipeline(config: PipelineConfig, out_dir: str | Path, sources: dict[str, str | Path] | None = None,
                 targets: list[str] | None = None, show_progress: bool = True) -> RunReport:
    return Runner(config, out_dir, sources, show_progress=show_progress).run(targets)
