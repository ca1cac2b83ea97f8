"""The on-disk cache of node outputs.

Each node's outputs live in OUT/cache/<node>/<key>/, where key is a digest of everything that determines them:
the node type, its code version, its config, the fingerprints of the settings and sources it reads, and the keys
of the outputs wired into it. A changed parameter changes the key of its node and, through the input keys, of
every node downstream, and of nothing else.

An entry is built in a temporary folder beside its final place and renamed into place when complete (an atomic
rename), so a run killed at any moment leaves complete entries or none; a resumed run reuses the complete ones.

Entry layout:  outputs.json  the output structure (arrays and files referenced by name)
               arrays.npz    the arrays (reproducible bytes, m3c.io.npz)
               files/        files the node wrote (videos, pictures)
               meta.json     node, type, key material, seconds, m3c version (not part of the outputs)
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from m3c.io.manifest import file_sha256
from m3c.io.npz import write_npz
from m3c.pipeline.node import FileRef, PipelineError

KEY_LENGTH = 20  # hex digits of the sha256 used in folder names


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal data gives equal text (and so equal keys)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True, default=_json_default)


def _json_default(value):
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        return value.item()
    if isinstance(value, np.ndarray):
        return {"__ndarray__": hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest(),
                "dtype": str(value.dtype), "shape": list(value.shape)}
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot put {type(value).__name__} into a cache key")


def digest(material: Any) -> str:
    return hashlib.sha256(canonical_json(material).encode()).hexdigest()[:KEY_LENGTH]


_FILE_DIGESTS: dict[tuple, str] = {}


def file_digest(path: str | Path) -> str:
    """sha256 of a file's content (memoised per path, size and modification time within this process)."""
    path = Path(path)
    stat = path.stat()
    memo = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if memo not in _FILE_DIGESTS:
        _FILE_DIGESTS[memo] = file_sha256(path)
    return _FILE_DIGESTS[memo]


# Output values <-> (JSON structure, arrays) ---------------------------------------------------------------------
def encode(value: Any, arrays: dict[str, np.ndarray], where: str) -> Any:
    """Replaces arrays by {"__array__": name} (collecting them in `arrays`) and FileRefs by {"__file__": path}."""
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise PipelineError(f"{where}: object arrays cannot be cached; use numbers or fixed-width strings")
        name = f"a{len(arrays)}"
        arrays[name] = value
        return {"__array__": name}
    if isinstance(value, FileRef):
        return {"__file__": value.path}
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str) or k.startswith("__"):
                raise PipelineError(f"{where}: dict keys must be strings not starting with '__', got {k!r}")
            out[k] = encode(v, arrays, f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        return [encode(v, arrays, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return {"__float__": repr(value)}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise PipelineError(f"{where}: cannot cache a {type(value).__name__}; node outputs are dicts, lists, numbers, "
                        "strings, numpy arrays and FileRefs")


def decode(obj: Any, arrays, files_dir: Path) -> Any:
    if isinstance(obj, dict):
        if "__array__" in obj:
            return arrays[obj["__array__"]]
        if "__file__" in obj:
            return FileRef(str(_inside(files_dir, obj["__file__"])))
        if "__float__" in obj:
            return float(obj["__float__"])
        return {k: decode(v, arrays, files_dir) for k, v in obj.items()}
    if isinstance(obj, list):
        return [decode(v, arrays, files_dir) for v in obj]
    return obj


def _inside(files_dir: Path, name: Any) -> Path:
    """files_dir / name, refused unless it stays inside files_dir (a cache entry could be edited or handed over:
    its file names are data, not paths to follow)."""
    if not isinstance(name, str) or not name or Path(name).is_absolute():
        raise PipelineError(f"cache entry {files_dir.parent}: file name {name!r} is not a relative path inside "
                            "its files/ folder; delete that entry to recompute it")
    path = files_dir / name
    root = files_dir.resolve()
    if not path.resolve().is_relative_to(root):
        raise PipelineError(f"cache entry {files_dir.parent}: file {name!r} points outside its files/ folder "
                            f"({path.resolve()}); delete that entry to recompute it")
    return path


class CacheEntryWriter:
    """A cache entry being built in a temporary folder; commit() renames it into place."""

    def __init__(self, final: Path):
        self.final = final
        self.tmp = final.parent / f".tmp-{final.name}-{uuid.uuid4().hex[:8]}"
        self.files_dir = self.tmp / "files"
        self.files_dir.mkdir(parents=True)

    def commit(self, outputs: dict[str, Any], meta: dict, node: str) -> None:
        arrays: dict[str, np.ndarray] = {}
        structure = encode(outputs, arrays, f"node {node!r} outputs")
        for ref in _file_refs(outputs):
            if not (self.files_dir / ref.path).is_file():
                raise PipelineError(f"node {node!r} returned FileRef({ref.path!r}) but wrote no such file in its "
                                    "work folder (ctx.work_dir)")
        write_npz(self.tmp / "arrays.npz", arrays)
        (self.tmp / "outputs.json").write_text(json.dumps(structure, indent=1, sort_keys=True) + "\n")
        (self.tmp / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True, default=_json_default) + "\n")
        _fsync_tree(self.tmp)
        if self.final.exists():  # an identical entry committed meanwhile (same key = same content)
            shutil.rmtree(self.tmp)
            return
        os.rename(self.tmp, self.final)
        _fsync_dir(self.final.parent)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


def _file_refs(value):
    if isinstance(value, FileRef):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from _file_refs(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _file_refs(v)


def _fsync_tree(root: Path) -> None:
    for path in sorted(root.rglob("*")):
        if path.is_file():
            with open(path, "rb") as fh:
                os.fsync(fh.fileno())
    for path in [root, *sorted(p for p in root.rglob("*") if p.is_dir())]:
        _fsync_dir(path)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Cache:
    """OUT/cache: one folder per node name, one entry per key."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def entry(self, node: str, key: str) -> Path:
        return self.root / node / key

    def has(self, node: str, key: str) -> bool:
        return (self.entry(node, key) / "outputs.json").is_file()

    def writer(self, node: str, key: str) -> CacheEntryWriter:
        (self.root / node).mkdir(parents=True, exist_ok=True)
        return CacheEntryWriter(self.entry(node, key))

    def load(self, node: str, key: str) -> dict[str, Any]:
        folder = self.entry(node, key)
        try:
            structure = json.loads((folder / "outputs.json").read_text())
            with np.load(folder / "arrays.npz", allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
        except (OSError, ValueError) as err:
            raise PipelineError(f"cache entry {folder} is unreadable ({err}); delete that folder to recompute it") \
                from None
        return decode(structure, arrays, folder / "files")

    def meta(self, node: str, key: str) -> dict:
        return json.loads((self.entry(node, key) / "meta.json").read_text())

    def remove_stale_temporaries(self) -> int:
        """Deletes the temporary folders of entries that a killed run left unfinished. Call with the run lock."""
        removed = 0
        if self.root.is_dir():
            for tmp in self.root.glob("*/.tmp-*"):
                shutil.rmtree(tmp, ignore_errors=True)
                removed += 1
        return removed
