"""The `load` node: outputs read from a folder instead of computed, e.g. perception results produced by another
tool (converted to the contracts of m3c.nodes.records), or a node's cache entry copied from another run.

    detections:
      type: load
      config: {path: my_perception/detections, outputs: [detections]}

The folder holds outputs.json and arrays.npz as written by save_outputs (the cache entry format).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from m3c.io.npz import write_npz
from m3c.pipeline import InputError, Node, register_node
from m3c.pipeline.cache import Cache, encode, file_digest


def save_outputs(folder: str | Path, outputs: dict) -> Path:
    """Writes node outputs (dicts, lists, numbers, strings, numpy arrays) to `folder` for a `load` node."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays: dict = {}
    structure = encode(outputs, arrays, str(folder))
    write_npz(folder / "arrays.npz", arrays)
    (folder / "outputs.json").write_text(json.dumps(structure, indent=1, sort_keys=True) + "\n")
    return folder


@register_node
class LoadNode(Node):
    type_name = "load"
    level = "frame"

    @dataclass
    class Config:
        path: str = ""
        outputs: list[str] = field(default_factory=list)

    def __init__(self, name: str, config=None):
        super().__init__(name, config)
        self.outputs = tuple(self.config.outputs)

    def _folder(self) -> Path:
        folder = Path(self.config.path).expanduser()
        if not (folder / "outputs.json").is_file() or not (folder / "arrays.npz").is_file():
            raise InputError(f"node {self.name!r}: {folder} holds no saved outputs (outputs.json and arrays.npz, "
                             "written by m3c.nodes.load.save_outputs)")
        return folder

    def key_config(self, ctx):
        folder = self._folder()
        return {"outputs": list(self.config.outputs), "content": [file_digest(folder / "outputs.json"),
                                                                  file_digest(folder / "arrays.npz")]}

    def run(self, ctx, inputs):
        folder = self._folder()
        values = Cache(folder.parent).load(folder.name, "")  # the same format as a cache entry
        missing = set(self.outputs) - set(values)
        if missing:
            raise InputError(f"node {self.name!r}: {folder} has no output(s) {sorted(missing)}; it has "
                             f"{sorted(values)}")
        return {k: values[k] for k in self.outputs}

