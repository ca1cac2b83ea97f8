"""Execution graph: topological order, cycle detection, wiring and config errors, Graphviz text."""

import itertools

import pytest
from pipeline_test_nodes import pipeline_yaml

from m3c.pipeline import Graph, PipelineConfig, PipelineError, topological_order
from m3c.pipeline.graph import render_dot


def is_topological(order, edges):
    position = {n: i for i, n in enumerate(order)}
    return all(position[a] < position[b] for a, b in edges)


def test_topological_order_respects_every_edge_and_config_order():
    names = ["a", "b", "c", "d", "e"]
    edges = [("d", "b"), ("a", "b"), ("b", "c"), ("e", "c")]
    order = topological_order(names, edges)
    assert sorted(order) == sorted(names)
    assert is_topological(order, edges)
    # Ready nodes are taken in config order: a and d and e are ready at start, a first.
    assert order == ["a", "d", "b", "e", "c"]


def test_topological_order_on_all_small_dags():
    # Every DAG over 4 labelled nodes whose edges go from lower to higher index, nodes listed in reverse.
    names = ["n3", "n2", "n1", "n0"]
    pairs = [(f"n{i}", f"n{j}") for i, j in itertools.combinations(range(4), 2)]
    for mask in range(1 << len(pairs)):
        edges = [p for k, p in enumerate(pairs) if mask >> k & 1]
        order = topological_order(names, edges)
        assert sorted(order) == sorted(names) and is_topological(order, edges), edges


@pytest.mark.parametrize("edges, cycle", [
    ([("a", "a")], ["a", "a"]),
    ([("a", "b"), ("b", "a")], ["a", "b", "a"]),
    ([("x", "a"), ("a", "b"), ("b", "c"), ("c", "a"), ("c", "y")], ["a", "b", "c", "a"]),
])
def test_cycle_is_detected_and_named(edges, cycle):
    names = sorted({n for e in edges for n in e})
    with pytest.raises(PipelineError, match="cycle") as err:
        topological_order(names, edges)
    text = str(err.value).split(": ", 1)[1].split(";")[0]
    found = text.split(" -> ")
    assert found[0] == found[-1]
    # The named cycle is the real one, up to where it starts.
    ring = cycle[:-1]
    start = ring.index(found[0])
    assert found[:-1] == ring[start:] + ring[:start]


def test_cycle_in_yaml_config():
    config = PipelineConfig.from_yaml("""
nodes:
  a: {type: t_slow, inputs: {x: b.data}}
  b: {type: t_slow, inputs: {x: a.data}}
""")
    with pytest.raises(PipelineError, match="cycle: a -> b -> a|cycle: b -> a -> b"):
        Graph.from_config(config)


def test_graph_from_test_pipeline():
    graph = Graph.from_config(PipelineConfig.from_yaml(pipeline_yaml()))
    assert graph.order == ["source", "other", "slow_a", "slow_b", "total", "report"]
    assert graph.upstream(["slow_b"]) == {"source", "slow_a", "slow_b"}
    assert graph.downstream(["other"]) == {"other", "total", "report"}
    dot = graph.to_dot({"source": "cached"})
    assert '"slow_a" -> "slow_b";' in dot
    assert 'subgraph "cluster_output"' in dot and dot.startswith("digraph m3c {")


@pytest.mark.parametrize("yaml_text, message", [
    ("nodes:\n  a: {type: nope}", "unknown node type 'nope'"),
    ("nodes:\n  a: {type: t_slow}", "input slot 'x' is not wired"),
    ("nodes:\n  a: {type: t_source}\n  b: {type: t_slow, inputs: {x: a.values}}", "node 'a' has no output 'values'"),
    ("nodes:\n  b: {type: t_slow, inputs: {x: zz.data}}", "does not name a node's output"),
    ("nodes:\n  b: {type: t_slow, inputs: {y: zz.data}}", "has no input slot"),
    ("nodes:\n  a: {type: t_source, config: {seed: 1.5}}", "setting 'seed': expected an integer, got 1.5"),
    ("nodes:\n  a: {type: t_source, config: {sed: 1}}", "unknown setting"),
    ("nodes:\n  a: {type: t_slow, config: {delay: yes}, inputs: {x: a.data}}", "expected a number"),
    ("settings: {body_modle: x}\nnodes:\n  a: {type: t_source}", "unknown setting"),
    ("nodes: [1, 2]", "non-empty mapping"),
    ("nodes:\n  a: {type: t_source}\nextra: 1", "unknown top-level"),
    ("nodes: {a: [", "not valid YAML"),
])
def test_config_errors_name_the_problem(yaml_text, message):
    with pytest.raises(PipelineError, match=message):
        Graph.from_config(PipelineConfig.from_yaml(yaml_text))


def test_optional_input_may_be_left_unwired():
    graph = Graph.from_config(PipelineConfig.from_yaml("""
nodes:
  a: {type: t_source}
  s: {type: t_sum, inputs: {a: a.data}}
"""))
    assert [(e.source, e.slot) for e in graph.edges] == [("a", "a")]


def test_overrides_and_round_trip():
    config = PipelineConfig.from_yaml(pipeline_yaml())
    changed = config.with_overrides({"slow_a.scale": 2, "settings.device": "cuda"})
    assert changed.nodes["slow_a"].config["scale"] == 2 and changed.settings.device == "cuda"
    assert config.nodes["slow_a"].config.get("scale") is None  # the original is untouched
    assert PipelineConfig.from_yaml(changed.to_yaml()).to_mapping() == changed.to_mapping()
    with pytest.raises(PipelineError, match="no node named 'nope'"):
        config.with_overrides({"nope.x": 1})


def test_render_dot_text_and_svg(tmp_path):
    import shutil

    dot = Graph.from_config(PipelineConfig.from_yaml(pipeline_yaml())).to_dot()
    assert render_dot(dot, tmp_path / "g.dot").read_text() == dot
    if shutil.which("dot"):
        svg = render_dot(dot, tmp_path / "g.svg").read_text()
        assert "<svg" in svg and "slow_b" in svg
    else:
        with pytest.raises(PipelineError, match="apt-get install graphviz"):
            render_dot(dot, tmp_path / "g.svg")
