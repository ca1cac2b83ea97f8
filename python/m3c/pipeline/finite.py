"""The finite-values check at every node boundary: a NaN or inf that leaves a node is named (node, output array,
frames) instead of travelling on to the optimizer, where it only shows as a NaN objective.

What is checked: every float array and float in a node's outputs (nested dicts and lists), except the paths the
node type declares may hold non-finite values (Node.nonfinite_outputs: fnmatch patterns over paths such as
"result.stages[].objective_before", list indices written "[]"). Person tracks (dicts with a "track_id" inside a
list) are the unit the later stages can do without: a track with a non-finite value is dropped from the outputs
with a warning that names it, the array and its frames; anything else non-finite stops the run with a
PipelineError that says the same.
"""

from __future__ import annotations

import fnmatch
import logging
from typing import Any

import numpy as np

from m3c.pipeline.node import PipelineError


def index_ranges(indices: np.ndarray, limit: int = 6) -> str:
    """'3-5, 9, 12-20' for sorted integer indices (the first `limit` runs, then how many more)."""
    if len(indices) == 0:
        return ""
    breaks = np.flatnonzero(np.diff(indices) != 1)
    starts = np.r_[indices[0], indices[breaks + 1]]
    stops = np.r_[indices[breaks], indices[-1]]
    runs = [f"{a}" if a == b else f"{a}-{b}" for a, b in zip(starts, stops)]
    more = f" and {len(runs) - limit} more run(s)" if len(runs) > limit else ""
    return ", ".join(runs[:limit]) + more


def _bad_rows(value: np.ndarray) -> np.ndarray:
    """Indices along the first axis holding a non-finite value (index 0 for a 0-d array)."""
    if value.size == 0:
        return np.zeros(0, dtype=np.int64)
    bad = ~np.isfinite(value)
    if value.ndim == 0:
        return np.array([0]) if bad else np.zeros(0, dtype=np.int64)
    return np.flatnonzero(bad.reshape(len(value), -1).any(axis=1))


def nonfinite_values(value: Any, path: str, allowed: tuple[str, ...] = (),
                     pattern_path: str | None = None) -> list[tuple[str, np.ndarray, int]]:
    """(path, bad first-axis indices, first-axis length) of every float array or float under `value` that holds NaN/inf and whose
    path in pattern form (pattern_path, default `path`; list indices as "[]") matches none of `allowed`."""
    found: list[tuple[str, np.ndarray, int]] = []

    def visit(v: Any, shown: str, pattern_path: str) -> None:
        if any(fnmatch.fnmatchcase(pattern_path, p) for p in allowed):
            return
        if isinstance(v, dict):
            for key, item in v.items():
                visit(item, f"{shown}.{key}", f"{pattern_path}.{key}")
        elif isinstance(v, (list, tuple)):
            for i, item in enumerate(v):
                visit(item, f"{shown}[{i}]", f"{pattern_path}[]")
        elif isinstance(v, np.ndarray) and v.dtype.kind in "fc":
            rows = _bad_rows(v)
            if len(rows):
                found.append((shown, rows, len(v) if v.ndim else 0))
        elif isinstance(v, (float, np.floating)) and not np.isfinite(v):
            found.append((shown, np.zeros(0, dtype=np.int64), 0))

    visit(value, path, path if pattern_path is None else pattern_path)
    return found


def _describe(path: str, rows: np.ndarray, first_frame: int | None) -> str:
    if not len(rows):
        return f"{path} is not finite"
    if first_frame is not None:
        return f"{path} is not finite in frames {index_ranges(rows + first_frame)}"
    return f"{path} is not finite in rows {index_ranges(rows)}"


def check_outputs(node_name: str, type_name: str, outputs: dict[str, Any], allowed: tuple[str, ...],
                  log: logging.Logger) -> dict[str, Any]:
    """The outputs with every person track that holds a non-finite value dropped (warned about); raises
    PipelineError for any other non-finite value and when every track of a list was dropped."""
    who = f"node {node_name!r} ({type_name})"

    def clean(v: Any, path: str, pattern_path: str) -> Any:
        if any(fnmatch.fnmatchcase(pattern_path, p) for p in allowed):
            return v
        if isinstance(v, dict):
            return {key: clean(item, f"{path}.{key}", f"{pattern_path}.{key}") for key, item in v.items()}
        if isinstance(v, list) and v and all(isinstance(t, dict) and "track_id" in t for t in v):
            kept = []
            for i, track in enumerate(v):
                bad = nonfinite_values(track, f"{path}[{i}]", allowed, f"{pattern_path}[]")
                if not bad:
                    kept.append(track)
                    continue
                first, n = track.get("first_frame"), track.get("num_frames")
                # Rows of a per-frame array (as long as the track) are reported as video frames.
                reasons = "; ".join(_describe(p.removeprefix(f"{path}[{i}]."), r,
                                              int(first) if first is not None and length == n else None)
                                    for p, r, length in bad)
                log.warning("%s: track %s dropped: %s", who, track["track_id"], reasons)
            if not kept:
                raise PipelineError(f"{who}: every track in {path} holds non-finite values and was dropped (see the "
                                    "warnings above); the node's inputs or its computation produced NaN/inf")
            return kept
        bad = nonfinite_values(v, path, allowed, pattern_path)
        if bad:
            details = "; ".join(_describe(p, r, None) for p, r, _ in bad[:5])
            more = f" (and {len(bad) - 5} more)" if len(bad) > 5 else ""
            raise PipelineError(f"{who} produced NaN/inf: {details}{more}. This is a bug in the node or in its "
                                "inputs; no later node would see it as anything but a NaN result")
        return v

    return {name: clean(value, name, name) for name, value in outputs.items()}

