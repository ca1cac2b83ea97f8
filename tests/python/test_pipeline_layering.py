"""The pipeline framework stands on its own: building and running a graph loads no domain package (no C++ core,
no body model, no built-in node); the program that builds M3C's graphs registers the built-in nodes itself."""

import json
import subprocess
import sys
from pathlib import Path

import m3c
from pipeline_test_nodes import pipeline_yaml

from m3c.pipeline import PipelineConfig

PYTHON_DIR = str(Path(m3c.__file__).resolve().parents[1])
TESTS_DIR = str(Path(__file__).resolve().parent)

SCRIPT = """
import json, sys
sys.path[:0] = [{python!r}, {tests!r}]
import pipeline_test_nodes
from m3c.pipeline import PipelineConfig, node_types, run_pipeline
report = run_pipeline(PipelineConfig.from_yaml(pipeline_test_nodes.pipeline_yaml()), {out!r}, show_progress=False)
loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith(("m3c._core", "m3c.nodes", "m3c.body")))
print("@@" + json.dumps({{"ran": report.ran(), "loaded": loaded, "types": sorted(node_types())}}))
"""


def run_child(code: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("@@"))[2:])


def test_running_the_framework_test_graph_loads_no_domain_package(tmp_path):
    outcome = run_child(SCRIPT.format(python=PYTHON_DIR, tests=TESTS_DIR, out=str(tmp_path / "out")))
    assert sorted(outcome["ran"]) == sorted(PipelineConfig.from_yaml(pipeline_yaml()).nodes)
    assert outcome["loaded"] == []
    assert outcome["types"] and all(t.startswith("t_") for t in outcome["types"])


def test_builtin_nodes_are_registered_by_the_composition_root():
    code = f"""
import json, sys
sys.path.insert(0, {PYTHON_DIR!r})
from m3c.pipeline import Graph, PipelineConfig, PipelineError
try:
    Graph.from_config(PipelineConfig.default())
    before = "built"
except PipelineError as err:
    before = str(err)
core_before = "m3c._core" in sys.modules
from m3c.nodes import register_builtin_nodes
register_builtin_nodes()
graph = Graph.from_config(PipelineConfig.default())
print("@@" + json.dumps({{"before": before, "nodes": len(graph.nodes), "core_before": core_before,
                         "core": "m3c._core" in sys.modules}}))
"""
    outcome = run_child(code)
    assert "unknown node type 'frames'" in outcome["before"]
    assert "m3c.nodes.register_builtin_nodes()" in outcome["before"]
    assert outcome["nodes"] == len(PipelineConfig.default().nodes)
    assert not outcome["core_before"] and outcome["core"]

