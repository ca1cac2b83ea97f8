"""Cheap deterministic node types for the pipeline framework tests (imported by the tests and by the
subprocesses they kill). Each run appends its node name to $M3C_TEST_RUN_LOG when set, to see what ran."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from m3c.io.npz import write_npz
from m3c.pipeline import FileRef, Node, register_node


def _log_run(name: str) -> None:
    log = os.environ.get("M3C_TEST_RUN_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(name + "\n")


@register_node
class SourceNode(Node):
    type_name = "t_source"
    outputs = ("data",)

    @dataclass
    class Config:
        seed: int = 0
        n: int = 8
        fail: bool = False

    def run(self, ctx, inputs):
        _log_run(self.name)
        if self.config.fail:
            raise RuntimeError("t_source was told to fail")
        rng = np.random.default_rng(self.config.seed)
        return {"data": {"values": rng.normal(size=self.config.n), "label": f"seed{self.config.seed}"}}


@register_node
class SlowNode(Node):
    """Transforms its input step by step with a pause per step: a node long enough to be killed midway."""

    type_name = "t_slow"
    inputs = ("x",)
    outputs = ("data",)

    @dataclass
    class Config:
        steps: int = 10
        delay: float = 0.0
        scale: float = 1.0

    def run(self, ctx, inputs):
        _log_run(self.name)
        x = np.asarray(inputs["x"]["values"], dtype=np.float64)
        acc = np.zeros_like(x)
        with ctx.progress("steps", self.config.steps) as bar:
            for i in range(self.config.steps):
                acc = np.tanh(acc + self.config.scale * x * (i + 1))
                time.sleep(self.config.delay)
                bar.update()
        return {"data": {"values": acc, "steps": self.config.steps}}


@register_node
class SumNode(Node):
    type_name = "t_sum"
    level = "track"
    inputs = ("a", "b")
    optional_inputs = ("b",)
    outputs = ("data",)

    def run(self, ctx, inputs):
        _log_run(self.name)
        total = np.asarray(inputs["a"]["values"]).copy()
        if inputs["b"] is not None:
            total = total + np.asarray(inputs["b"]["values"])
        return {"data": {"values": total, "parts": [inputs["a"].get("label", "a"), "b" if inputs["b"] else None]}}


@register_node
class ReportNode(Node):
    """Writes a text file and an .npz (published into the output folder)."""

    type_name = "t_report"
    level = "output"
    inputs = ("x",)
    outputs = ("report", "arrays")
    publish = {"report": "report.txt", "arrays": "arrays.npz"}

    @dataclass
    class Config:
        fail: bool = False

    def run(self, ctx, inputs):
        _log_run(self.name)
        values = np.asarray(inputs["x"]["values"])
        with open(ctx.work_path("report.txt"), "w") as fh:
            fh.write(" ".join(f"{v:.17g}" for v in values) + "\n")
        if self.config.fail:
            raise RuntimeError("t_report was told to fail")
        write_npz(ctx.work_path("arrays.npz"), {"values": values.astype(np.float32)})
        return {"report": FileRef("report.txt"), "arrays": FileRef("arrays.npz")}


@register_node
class NoteNode(Node):
    """A second published file (note.txt) from another node, for runs that publish only some of the files."""

    type_name = "t_note"
    level = "output"
    inputs = ("x",)
    outputs = ("note",)
    publish = {"note": "note.txt"}

    def run(self, ctx, inputs):
        _log_run(self.name)
        with open(ctx.work_path("note.txt"), "w") as fh:
            fh.write(f"sum {float(np.sum(inputs['x']['values'])):.17g}\n")
        return {"note": FileRef("note.txt")}


@register_node
class ModelNode(Node):
    """Records load/run/unload order to check that models live only while their node runs."""

    type_name = "t_model"
    inputs = ("x",)
    outputs = ("data",)
    events: list = []

    def load(self, ctx):
        ModelNode.events.append(("load", self.name))
        self.model = np.ones(3)

    def run(self, ctx, inputs):
        ModelNode.events.append(("run", self.name, hasattr(self, "model")))
        return {"data": {"values": np.asarray(inputs["x"]["values"]) * self.model.sum()}}

    def unload(self):
        ModelNode.events.append(("unload", self.name))
        del self.model


TEST_PIPELINE = """
nodes:
  source:
    type: t_source
    config: {seed: 3, n: 6}
  other:
    type: t_source
    config: {seed: 4, n: 6}
  slow_a:
    type: t_slow
    inputs: {x: source.data}
    config: {steps: 12, delay: %(delay)s}
  slow_b:
    type: t_slow
    inputs: {x: slow_a.data}
    config: {steps: 12, delay: %(delay)s, scale: 0.5}
  total:
    type: t_sum
    inputs: {a: slow_b.data, b: other.data}
  report:
    type: t_report
    inputs: {x: total.data}
"""


def pipeline_yaml(delay: float = 0.0) -> str:
    return TEST_PIPELINE % {"delay": delay}
