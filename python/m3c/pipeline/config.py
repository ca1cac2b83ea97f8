"""Pipeline configuration in YAML: global settings and the nodes with their wiring and settings.

    settings:
      body_model: null          # SMPL-layout model file; null = M3C's open model
    nodes:
      frames:                   # the node's name (unique)
        type: frames            # its node type (default: the name)
        config: {start: 0}      # the type's settings (its Config dataclass)
      camera:
        type: camera
        inputs: {video: frames.video}   # input slot -> <node>.<output>
        needs: {cpus: 1, memory_gb: 0.5}  # optional: cores and memory while it runs (m3c batch's Ray request)

The default pipeline ships as m3c/pipeline/default.yaml.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from m3c.pipeline.node import InputError, Needs, PipelineError, config_from_dict


@dataclass
class Settings:
    """Settings several nodes read. A node lists those it reads (Node.settings); only those enter its key.

    body_model: SMPL-layout body model file (.pkl/.npz); None = the open model shipped with M3C.
    models_dir: folder of learned-model checkpoints (overrides $M3C_MODELS).
    device: torch device for learned models.
    visualize: also write each node's pictures (Node.visualize) under OUT/viz/<node>/.
    """

    body_model: str | None = None
    models_dir: str | None = None
    device: str = "cpu"
    visualize: bool = False


def check_settings(settings: Settings) -> None:
    """Settings that name something on this machine: it must exist, or the run stops before any node (a missing
    checkpoint folder would otherwise quietly run every network on its fallback; a missing GPU fail late)."""
    if settings.models_dir is not None:
        folder = Path(settings.models_dir).expanduser()
        if not folder.is_dir():
            raise InputError(f"settings.models_dir (--checkpoints) {folder} is not a folder; give the folder that "
                             "holds the checkpoints, or leave it out to use $M3C_MODELS")
    check_device(settings.device)


def check_device(device: str) -> None:
    """settings.device names a torch device this machine has (cpu; cuda / cuda:N with N below the GPU count;
    mps where it is available)."""
    if device == "cpu":
        return
    try:
        import torch
    except ImportError:
        raise InputError(f"settings.device={device!r} needs torch, which is not installed; use cpu") from None
    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError, ValueError) as err:
        raise InputError(f"settings.device={device!r} is not a torch device ({err}); use cpu or cuda:N") from None
    if parsed.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise InputError(f"settings.device={device!r}: this machine has no CUDA GPU that torch can use "
                             f"(torch {torch.__version__}); use --set settings.device=cpu")
        if parsed.index is not None and parsed.index >= count:
            raise InputError(f"settings.device={device!r}: this machine has {count} CUDA GPU(s), cuda:0 .. "
                             f"cuda:{count - 1}")
    elif parsed.type == "mps":
        if not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise InputError(f"settings.device={device!r}: MPS is not available on this machine; use cpu")
    elif parsed.type != "cpu":
        raise InputError(f"settings.device={device!r}: M3C runs its networks on cpu, cuda or mps")


@dataclass
class NodeEntry:
    name: str
    type: str
    inputs: dict[str, str] = field(default_factory=dict)  # slot -> "node.output"
    config: dict[str, Any] = field(default_factory=dict)
    needs: dict[str, float] | None = None  # cpus / memory_gb while it runs (pipeline.node.Needs); not in cache keys


@dataclass
class PipelineConfig:
    settings: Settings
    nodes: dict[str, NodeEntry]  # in file order

    @classmethod
    def from_mapping(cls, raw: Any, where: str = "pipeline config") -> "PipelineConfig":
        if not isinstance(raw, dict):
            raise PipelineError(f"{where}: expected a mapping with 'settings' and 'nodes', got {type(raw).__name__}")
        unknown = set(raw) - {"settings", "nodes"}
        if unknown:
            raise PipelineError(f"{where}: unknown top-level key(s) {sorted(unknown)}; expected 'settings', 'nodes'")
        settings = config_from_dict(Settings, raw.get("settings"), f"{where}: settings")
        nodes_raw = raw.get("nodes")
        if not isinstance(nodes_raw, dict) or not nodes_raw:
            raise PipelineError(f"{where}: 'nodes' must be a non-empty mapping of node name -> node")
        nodes = {}
        for name, entry in nodes_raw.items():
            entry = entry or {}
            if not isinstance(name, str) or not name.isidentifier():
                raise PipelineError(f"{where}: node name {name!r} must be an identifier (letters, digits, _)")
            if not isinstance(entry, dict):
                raise PipelineError(f"{where}: node {name!r} must be a mapping, got {entry!r}")
            bad = set(entry) - {"type", "inputs", "config", "needs"}
            if bad:
                raise PipelineError(f"{where}: node {name!r} has unknown key(s) {sorted(bad)}; "
                                    "expected 'type', 'inputs', 'config', 'needs'")
            inputs = entry.get("inputs") or {}
            if not isinstance(inputs, dict) or not all(isinstance(v, str) or v is None for v in inputs.values()):
                raise PipelineError(f"{where}: node {name!r}: 'inputs' must map slot -> '<node>.<output>'")
            config = entry.get("config") or {}
            if not isinstance(config, dict):
                raise PipelineError(f"{where}: node {name!r}: 'config' must be a mapping")
            needs = entry.get("needs")
            if needs is not None:
                Needs.from_dict(needs, f"{where}: node {name!r}")  # checked here, applied by the graph
            nodes[name] = NodeEntry(name, str(entry.get("type", name)),
                                    {k: v for k, v in inputs.items() if v is not None}, dict(config),
                                    dict(needs) if needs is not None else None)
        return cls(settings, nodes)

    @classmethod
    def from_yaml(cls, text_or_path: str | Path) -> "PipelineConfig":
        """From YAML text, or from a file when given a Path (or a str naming an existing .yaml/.yml file)."""
        where = "pipeline config"
        if isinstance(text_or_path, Path) or (isinstance(text_or_path, str) and "\n" not in text_or_path
                                              and text_or_path.endswith((".yaml", ".yml"))):
            path = Path(text_or_path)
            if not path.is_file():
                raise PipelineError(f"pipeline config file not found: {path}")
            where, text = str(path), path.read_text()
        else:
            text = text_or_path
        try:
            raw = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise PipelineError(f"{where}: not valid YAML: {err}") from None
        return cls.from_mapping(raw, where)

    @classmethod
    def default(cls) -> "PipelineConfig":
        return cls.from_yaml(default_config_text())

    def to_mapping(self) -> dict:
        nodes = {}
        for name, entry in self.nodes.items():
            item: dict[str, Any] = {"type": entry.type}
            if entry.inputs:
                item["inputs"] = dict(entry.inputs)
            if entry.config:
                item["config"] = copy.deepcopy(entry.config)
            if entry.needs is not None:
                item["needs"] = dict(entry.needs)
            nodes[name] = item
        return {"settings": dataclasses.asdict(self.settings), "nodes": nodes}

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_mapping(), sort_keys=False)

    def with_overrides(self, overrides: dict[str, Any]) -> "PipelineConfig":
        """A copy with `overrides` applied: "settings.<name>" or "<node>.<setting>" -> value."""
        raw = self.to_mapping()
        for dotted, value in overrides.items():
            head, _, key = dotted.partition(".")
            if not key:
                raise PipelineError(f"override {dotted!r}: expected 'settings.<name>' or '<node>.<setting>'")
            if head == "settings":
                raw["settings"][key] = value
            elif head in raw["nodes"]:
                raw["nodes"][head].setdefault("config", {})[key] = value
            else:
                raise PipelineError(f"override {dotted!r}: no node named {head!r}; nodes: {sorted(raw['nodes'])}")
        return self.from_mapping(raw, "pipeline config (with overrides)")


def parse_override(text: str) -> tuple[str, Any]:
    """'node.key=value' -> ("node.key", value parsed as YAML: numbers, true/false, null, [lists])."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise PipelineError(f"--set {text!r}: expected <node>.<setting>=<value>")
    try:
        return key.strip(), yaml.safe_load(value)
    except yaml.YAMLError as err:
        raise PipelineError(f"--set {text!r}: value is not valid YAML: {err}") from None


def default_config_path() -> Path:
    return Path(str(resources.files("m3c.pipeline") / "default.yaml"))


def default_config_text() -> str:
    path = default_config_path()
    if not path.is_file():
        raise PipelineError(f"the default pipeline config is missing from the installation ({path}); reinstall m3c")
    return path.read_text()
