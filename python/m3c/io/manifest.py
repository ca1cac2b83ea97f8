"""The manifest of an output folder: which run's files it holds, written last so a folder is published as a whole.

`m3c run` links a run's files into the folder and then writes OUT/manifest.json (atomically) with the run's key
(a digest of the cache keys of the nodes that produced them) and every file's size and SHA-256. A run that will
replace the files first rewrites the manifest as "running"; a run that fails rewrites it as "failed"; a run killed
leaves "running" behind. So a reader (`m3c info`, load_results) can tell a complete folder from one whose files
are stale, half replaced or modified since, and says which.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from m3c.io.atomic import atomic_path

MANIFEST = "manifest.json"
SCHEMA = "m3c.manifest/1"


class IncompleteResults(ValueError):
    """An output folder's files are not one complete run's (stale, interrupted, modified or unmanaged)."""


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def run_key(files: dict[str, dict]) -> str:
    """The digest of (file name, producing node, its cache key) of every published file."""
    material = json.dumps({name: [f.get("node"), f.get("key")] for name, f in sorted(files.items())})
    return hashlib.sha256(material.encode()).hexdigest()[:24]


def file_entry(path: Path, node: str | None = None, key: str | None = None) -> dict:
    return {"node": node, "key": key, "size": path.stat().st_size, "sha256": file_sha256(path)}


def read_manifest(folder: str | Path) -> dict | None:
    """The folder's manifest, None if it has none; ValueError if it is unreadable."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return None
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise IncompleteResults(f"{path} is unreadable ({err}); run `m3c run` again to rewrite it") from None
    if not isinstance(manifest, dict) or manifest.get("schema") != SCHEMA:
        raise IncompleteResults(f"{path}: not an M3C manifest of schema {SCHEMA!r}")
    return manifest


def write_manifest(folder: str | Path, manifest: dict) -> None:
    with atomic_path(Path(folder) / MANIFEST) as tmp:
        tmp.write_text(json.dumps({"schema": SCHEMA, **manifest}, indent=1, sort_keys=True) + "\n")


def seal(folder: str | Path, names: list[str]) -> dict:
    """Writes a complete manifest for files that were written into `folder` by other means than `m3c run` (e.g.
    results converted from another method), so that load_results accepts them. Returns the manifest."""
    folder = Path(folder)
    files = {name: file_entry(folder / name) for name in names}
    manifest = {"status": "complete", "run_key": run_key(files), "files": files}
    write_manifest(folder, manifest)
    return {"schema": SCHEMA, **manifest}


def running_manifest(folder: str | Path, planned: dict[str, dict], pid: int) -> dict:
    """The "running" manifest of a run that will publish `planned` ({file name: {node, key}}): it names the last
    complete run, whose files stay in the folder (or are partly replaced if the run is stopped)."""
    try:
        old = read_manifest(folder)
    except IncompleteResults:
        old = None
    previous = old if old is not None and old.get("status") == "complete" else (old or {}).get("previous")
    return {"status": "running", "run_key": run_key(planned) if planned else None,
            "started": time.strftime("%Y-%m-%d %H:%M:%S %z"), "pid": pid,
            "previous": {"run_key": previous.get("run_key"), "files": previous.get("files", {})} if previous else None}


def failed_manifest(running: dict, error: BaseException) -> dict:
    reason = "interrupted" if isinstance(error, KeyboardInterrupt) else f"{type(error).__name__}: {error}"
    return {**running, "status": "failed", "error": reason.splitlines()[0][:500]}


def mark_failed(folder: str | Path, error: BaseException) -> bool:
    """After a run that failed before it started (a bad option, a missing component): if the folder holds an
    earlier run's results, its manifest now says they are stale. Skipped while another run holds the folder."""
    folder = Path(folder)
    if not (folder / MANIFEST).is_file():
        return False
    lock = folder / "cache" / ".lock"
    with contextlib.ExitStack() as stack:
        if lock.is_file():
            fh = stack.enter_context(open(lock, "a"))
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False
            stack.callback(fcntl.flock, fh, fcntl.LOCK_UN)
        write_manifest(folder, failed_manifest(running_manifest(folder, {}, os.getpid()), error))
    return True


def _locked_by_a_run(folder: Path) -> bool:
    lock = folder / "cache" / ".lock"
    if not lock.is_file():
        return False
    with open(lock, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
    return False


@dataclass
class FolderState:
    """status: "complete", "running" (a run writes it now), "interrupted" (a run was killed before it finished),
    "failed" (the last run failed), "modified" (files differ from the manifest), "unmanaged" (files without a
    manifest) or "empty"; message: one line for people; files: the file names the manifest vouches for."""

    status: str
    message: str
    manifest: dict | None = None

    @property
    def complete(self) -> bool:
        return self.status == "complete"

    @property
    def files(self) -> list[str]:
        return sorted((self.manifest or {}).get("files", {})) if self.complete else []


def folder_state(folder: str | Path, known_files: tuple[str, ...] = ()) -> FolderState:
    """What the folder holds, checked against its manifest (sizes and SHA-256 of every listed file).
    known_files: names that count as results when there is no manifest."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    again = "run the same `m3c run` command again to finish it"
    if manifest is None:
        present = [name for name in known_files if (folder / name).exists()]
        if present:
            return FolderState("unmanaged", f"{', '.join(present)} without {MANIFEST}: left by a run killed while "
                                            f"publishing, or written by an older M3C or by hand; {again}")
        return FolderState("empty", "no results")
    status = manifest.get("status")
    started = manifest.get("started", "?")
    previous = manifest.get("previous") or {}
    kept = (f"the files here are those of the earlier run {previous['run_key']}"
            if previous.get("run_key") else "no earlier complete run's files are here")
    if status == "running":
        if _locked_by_a_run(folder):
            return FolderState("running", f"a run (pid {manifest.get('pid')}, started {started}) is writing this "
                                          "folder now", manifest)
        return FolderState("interrupted", f"stale: the run started {started} was stopped before it finished "
                                          f"({kept}, possibly partly replaced); {again}", manifest)
    if status == "failed":
        return FolderState("failed", f"stale: the last run (started {started}) failed: {manifest.get('error')}; "
                                     f"{kept}, not results of its settings", manifest)
    if status != "complete":
        return FolderState("modified", f"{MANIFEST} has unknown status {status!r}", manifest)
    for name, entry in sorted(manifest.get("files", {}).items()):
        path = folder / name
        # A manifest lists files of its own folder; one naming a path elsewhere (edited or handed over) is not
        # followed: its file would be read and hashed.
        if not isinstance(name, str) or Path(name).is_absolute() or \
                not path.resolve().is_relative_to(folder.resolve()):
            return FolderState("modified", f"{MANIFEST} lists {name!r}, which is not a file of this folder; "
                                           f"{again}", manifest)
        if not path.is_file():
            return FolderState("modified", f"{name} is missing (listed in {MANIFEST}); {again}", manifest)
        if path.stat().st_size != entry.get("size") or file_sha256(path) != entry.get("sha256"):
            return FolderState("modified", f"{name} was changed after the run that wrote it; {again}", manifest)
    return FolderState("complete", f"complete (run {manifest.get('run_key')})", manifest)


def check_complete(folder: str | Path, needed: tuple[str, ...]) -> FolderState:
    """folder_state, raising IncompleteResults unless the folder is complete and vouches for `needed`."""
    state = folder_state(folder, needed)
    if not state.complete:
        raise IncompleteResults(f"{folder}: {state.message}")
    missing = [name for name in needed if name not in state.files]
    if missing:
        raise IncompleteResults(f"{folder}: the run that published this folder did not write {', '.join(missing)}")
    return state
