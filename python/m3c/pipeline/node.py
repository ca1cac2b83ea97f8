"""The node interface: one step of the execution graph (seed thesis, section 4.1).

A node type declares the names of its input slots and outputs, a config dataclass, and `run`, which maps input
values to output values. Values are plain data: dicts, lists, strings, numbers, numpy arrays, and FileRef for
files the node writes into its work folder. The runner wires slots to other nodes' outputs, caches every node's
outputs on disk under a key made of the node's config, its code version and its inputs' keys, and calls
`load` before `run` and `unload` after it, so a node's models occupy memory only while it runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

# Levels of the thesis's execution graph (Figure 4.1), plus the result writers.
LEVELS = ("frame", "patch", "smpl", "track", "output")


class PipelineError(RuntimeError):
    """A pipeline cannot be built or run as configured; the message names the node and the fix."""


class InputError(PipelineError, ValueError):
    """The user's input (video, file, option) is unusable; the message says what is wrong with it."""


class ComponentUnavailable(PipelineError):
    """A node needs a component (a perception backend, a model file) that this installation does not have."""

    def __init__(self, node: str, what: str, fix: str):
        self.node, self.what, self.fix = node, what, fix
        super().__init__(f"node {node!r} needs {what}, which is not available: {fix}")


@dataclass(frozen=True)
class FileRef:
    """A file a node wrote into its work folder, by path relative to that folder. When the node's outputs are
    loaded from the cache, `path` is resolved to the committed entry (absolute)."""

    path: str


@dataclass(frozen=True)
class Needs:
    """What a node needs while it runs, for a scheduler that places whole runs on machines (`m3c batch` on Ray asks
    for the most that any node of the pipeline needs, since a run executes its nodes one after another).

    cpus: cores it keeps busy. memory_gb: the run process's peak resident memory while the node runs (interpreter
    and libraries included), as bench/long_video.py measures it; on a 10-minute 960 x 540 video unless the node's
    memory is bounded whatever the length."""

    cpus: float = 1.0
    memory_gb: float = 1.0

    @classmethod
    def from_dict(cls, values: dict, where: str) -> "Needs":
        """From a config mapping {cpus, memory_gb}; PipelineError naming `where` for anything else."""
        if not isinstance(values, dict) or set(values) - {"cpus", "memory_gb"}:
            raise PipelineError(f"{where}: 'needs' must be a mapping with cpus and/or memory_gb, got {values!r}")
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
                raise PipelineError(f"{where}: needs.{key} must be a number > 0, got {value!r}")
        return cls(**{k: float(v) for k, v in values.items()})


@dataclass
class NoConfig:
    """For nodes without settings."""


class Node:
    """Base class of every node type. Subclasses set the class attributes and implement `run`.

    type_name: registry name used in the YAML config (`type: frames`).
    inputs / outputs: slot names; `optional_inputs` may be left unwired (the slot's value is then None).
    Config: a dataclass of the node's settings (YAML `config:` section); validated on construction.
    settings: global settings this node reads (e.g. "body_model"); their fingerprints enter its cache key.
    sources: run sources this node reads (e.g. "video"); their content fingerprints enter its cache key.
    publish: output name -> file name under the run's output folder, for outputs that are FileRefs.
    nonfinite_outputs: output paths where NaN/inf is legal; elsewhere the runner stops the run (or drops the person
    track) at the first non-finite value, naming the node, the array and the frames.
    version: bump when the node's behaviour changes through code outside the class (its own source is hashed).
    needs: cores and memory the node needs while it runs (Needs); a pipeline config's node entry may declare its
    own (`needs: {cpus: 2, memory_gb: 1.5}`), which replaces it for that node.
    """

    type_name: ClassVar[str] = ""
    level: ClassVar[str] = "frame"
    inputs: ClassVar[tuple[str, ...]] = ()
    optional_inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    Config: ClassVar[type] = NoConfig
    settings: ClassVar[tuple[str, ...]] = ()
    sources: ClassVar[tuple[str, ...]] = ()
    publish: ClassVar[dict[str, str]] = {}
    version: ClassVar[str] = "1"
    # Output paths that may hold NaN/inf by design (fnmatch patterns, list indices as "[]", e.g.
    # "result.stages[].objective_before"); every other float must be finite (m3c.pipeline.finite).
    nonfinite_outputs: ClassVar[tuple[str, ...]] = ()
    needs: ClassVar[Needs] = Needs()

    def __init__(self, name: str, config: Any = None):
        self.name = name
        self.config = config if config is not None else self.Config()

    # Lifecycle -----------------------------------------------------------------------------------------
    def check(self, ctx) -> None:
        """Raises ComponentUnavailable (or InputError) when the node cannot run in this installation/config.
        Called for every node that will run, before any runs, so a run fails early and names all that is
        missing."""

    def load(self, ctx) -> None:
        """Loads models (weights, networks) onto ctx.device. Called right before run."""

    def run(self, ctx, inputs: dict[str, Any]) -> dict[str, Any]:
        raise NotImplementedError

    def unload(self) -> None:
        """Frees what load() created. Called after run, also when run raised."""

    def visualize(self, ctx, inputs: dict[str, Any], outputs: dict[str, Any], folder: Path) -> list[Path]:
        """Optional pictures of this node's outputs, written into `folder`; returns the files written."""
        return []

    # Cache key material ----------------------------------------------------------------------------------
    def key_config(self, ctx) -> dict:
        """The settings that determine this node's outputs (default: its whole config). Override to resolve
        defaults that live elsewhere, so that a changed default also changes the key."""
        return config_to_dict(self.config)

    @classmethod
    def code_version(cls) -> str:
        """The node's version string plus a digest of its class source: editing the node re-runs it."""
        if cls not in _SOURCE_DIGESTS:
            try:
                source = inspect.getsource(cls)
            except (OSError, TypeError):
                source = ""
            _SOURCE_DIGESTS[cls] = hashlib.sha256(source.encode()).hexdigest()[:16]
        return f"{cls.version}:{_SOURCE_DIGESTS[cls]}"


_SOURCE_DIGESTS: dict[type, str] = {}


_REGISTRY: dict[str, type[Node]] = {}


def register_node(cls: type[Node]) -> type[Node]:
    """Class decorator: makes a node type available to YAML configs under cls.type_name."""
    if not cls.type_name:
        raise TypeError(f"{cls.__name__} has no type_name")
    if cls.level not in LEVELS:
        raise TypeError(f"{cls.__name__}.level must be one of {LEVELS}, got {cls.level!r}")
    if not dataclasses.is_dataclass(cls.Config):
        raise TypeError(f"{cls.__name__}.Config must be a dataclass")
    unknown = set(cls.optional_inputs) - set(cls.inputs)
    if unknown:
        raise TypeError(f"{cls.__name__}.optional_inputs names unknown slots {sorted(unknown)}")
    existing = _REGISTRY.get(cls.type_name)
    if existing is not None and existing.__qualname__ != cls.__qualname__:
        raise TypeError(f"node type {cls.type_name!r} is registered twice ({existing.__name__}, {cls.__name__})")
    _REGISTRY[cls.type_name] = cls
    return cls


def node_type(type_name: str) -> type[Node]:
    try:
        return _REGISTRY[type_name]
    except KeyError:
        # The framework knows no node type of its own: the program that builds a graph registers the types it uses
        # (M3C's built-in ones: m3c.nodes.register_builtin_nodes(), which `m3c run` and the other commands call).
        raise PipelineError(f"unknown node type {type_name!r}; known types: {sorted(_REGISTRY)} (M3C's built-in "
                            "node types are registered by m3c.nodes.register_builtin_nodes())") from None


def node_types() -> dict[str, type[Node]]:
    return dict(_REGISTRY)


@dataclass(frozen=True)
class SettingLoader:
    """How the runner serves a global setting that names something to load (a model file): `fingerprint(value)` is
    what enters the cache keys of the nodes that read the setting (the file's content digest, not its path), and
    `load(value)` builds the object, once per run (RunContext.loaded). Registered by the program that builds the
    graph, next to its node types, so the framework names no domain package."""

    fingerprint: Callable[[Any], Any]
    load: Callable[[Any], Any]


_SETTING_LOADERS: dict[str, SettingLoader] = {}


def register_setting_loader(name: str, fingerprint: Callable[[Any], Any], load: Callable[[Any], Any]) -> None:
    """Makes Settings.<name> a loadable setting (see SettingLoader); registering it again replaces the loader."""
    _SETTING_LOADERS[name] = SettingLoader(fingerprint, load)


def setting_loader(name: str) -> SettingLoader | None:
    return _SETTING_LOADERS.get(name)


# Config dataclasses <-> YAML dicts ----------------------------------------------------------------------------
def config_to_dict(config: Any) -> dict:
    return dataclasses.asdict(config)


def config_from_dict(cls: type, values: dict | None, where: str) -> Any:
    """Builds dataclass `cls` from a YAML mapping, rejecting unknown keys and values of the wrong type."""
    values = dict(values or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(values) - set(fields)
    if unknown:
        raise PipelineError(f"{where}: unknown setting(s) {sorted(unknown)}; valid settings: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {name: _coerce(value, hints[name], f"{where}, setting {name!r}") for name, value in values.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise PipelineError(f"{where}: {err}") from None


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except PipelineError as err:
                errors.append(str(err))
        raise PipelineError(errors[0] if len(errors) == 1 else f"{where}: {value!r} matches none of {hint}")
    if hint is Any:
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise PipelineError(f"{where}: expected a list, got {value!r}")
        item = args[0] if args else Any
        return [_coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise PipelineError(f"{where}: expected a mapping, got {value!r}")
        return dict(value)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise PipelineError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise PipelineError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise PipelineError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise PipelineError(f"{where}: expected a string, got {value!r}")
        return value
    if typing.get_origin(hint) is typing.Literal:
        if value not in args:
            raise PipelineError(f"{where}: expected one of {list(args)}, got {value!r}")
        return value
    return value
