"""The execution graph: nodes built from a PipelineConfig, wiring checks, topological order, Graphviz text."""

from __future__ import annotations

import heapq
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from m3c.pipeline.config import PipelineConfig
from m3c.pipeline.node import Needs, Node, PipelineError, config_from_dict, node_type


@dataclass(frozen=True)
class Edge:
    source: str  # producing node
    output: str  # its output
    target: str  # consuming node
    slot: str  # the consumer's input slot


class Graph:
    """Nodes and the edges between them; `order` is a topological order (ties broken by config order)."""

    def __init__(self, nodes: dict[str, Node], edges: list[Edge]):
        self.nodes = nodes
        self.edges = edges
        self.order = topological_order(list(nodes), [(e.source, e.target) for e in edges])

    @classmethod
    def from_config(cls, config: PipelineConfig) -> "Graph":
        nodes: dict[str, Node] = {}
        for name, entry in config.nodes.items():
            node_cls = node_type(entry.type)
            node_config = config_from_dict(node_cls.Config, entry.config, f"node {name!r} ({entry.type})")
            nodes[name] = node_cls(name, node_config)
            if entry.needs is not None:
                nodes[name].needs = Needs.from_dict(entry.needs, f"node {name!r}")
        edges = []
        for name, entry in config.nodes.items():
            node = nodes[name]
            unknown = set(entry.inputs) - set(node.inputs)
            if unknown:
                raise PipelineError(f"node {name!r} ({entry.type}) has no input slot(s) {sorted(unknown)}; "
                                    f"its slots: {list(node.inputs)}")
            for slot in node.inputs:
                ref = entry.inputs.get(slot)
                if ref is None:
                    if slot in node.optional_inputs:
                        continue
                    raise PipelineError(f"node {name!r} ({entry.type}): input slot {slot!r} is not wired; "
                                        f"set inputs: {{{slot}: <node>.<output>}}")
                source, dot, output = ref.partition(".")
                if not dot or source not in nodes:
                    raise PipelineError(f"node {name!r}: input {slot}: {ref!r} does not name a node's output "
                                        f"(<node>.<output>; nodes: {sorted(nodes)})")
                if output not in nodes[source].outputs:
                    raise PipelineError(f"node {name!r}: input {slot}: node {source!r} has no output {output!r}; "
                                        f"its outputs: {list(nodes[source].outputs)}")
                edges.append(Edge(source, output, name, slot))
        return cls(nodes, edges)

    def inputs_of(self, name: str) -> list[Edge]:
        return [e for e in self.edges if e.target == name]

    def upstream(self, names) -> set[str]:
        """`names` and every node they depend on."""
        todo, seen = list(names), set()
        while todo:
            name = todo.pop()
            if name in seen:
                continue
            seen.add(name)
            todo.extend(e.source for e in self.inputs_of(name))
        return seen

    def downstream(self, names) -> set[str]:
        """`names` and every node that depends on them."""
        todo, seen = list(names), set()
        while todo:
            name = todo.pop()
            if name in seen:
                continue
            seen.add(name)
            todo.extend(e.target for e in self.edges if e.source == name)
        return seen

    def to_dot(self, status: dict[str, str] | None = None) -> str:
        """Graphviz text: one cluster per thesis level, edges labelled with the output they carry.
        status (node -> 'cached'/'ran'/'failed'/...) colours the nodes of a finished run."""
        colours = {"cached": "#d9ead3", "ran": "#cfe2f3", "failed": "#f4cccc", "unavailable": "#fce5cd"}
        lines = ["digraph m3c {", "  rankdir=LR;", '  node [shape=box, style="rounded,filled", fillcolor="#ffffff",'
                 ' fontname="Helvetica"];', '  edge [fontname="Helvetica", fontsize=9];']
        levels: dict[str, list[str]] = {}
        for name in self.order:
            levels.setdefault(self.nodes[name].level, []).append(name)
        for level, names in levels.items():
            lines.append(f'  subgraph "cluster_{level}" {{')
            title = "SMPL" if level == "smpl" else level
            lines.append(f'    label="{title}-level"; style=dashed; color="#999999";')
            for name in names:
                node = self.nodes[name]
                label = name if node.type_name == name else f"{name}\\n({node.type_name})"
                fill = colours.get((status or {}).get(name, ""), "#ffffff")
                lines.append(f'    "{name}" [label="{label}", fillcolor="{fill}"];')
            lines.append("  }")
        for e in self.edges:
            # Label only the outputs of nodes that have several (one-output edges are named by their source).
            label = f' [label="{e.output}"]' if len(self.nodes[e.source].outputs) > 1 else ""
            lines.append(f'  "{e.source}" -> "{e.target}"{label};')
        lines.append("}")
        return "\n".join(lines) + "\n"


def topological_order(names: list[str], edges: list[tuple[str, str]]) -> list[str]:
    """Kahn's algorithm; among ready nodes the one listed first in `names` goes first, so the order is stable.
    Raises PipelineError naming a cycle when there is one."""
    position = {n: i for i, n in enumerate(names)}
    indegree = {n: 0 for n in names}
    successors: dict[str, list[str]] = {n: [] for n in names}
    for a, b in edges:
        successors[a].append(b)
        indegree[b] += 1
    ready = [(position[n], n) for n in names if indegree[n] == 0]
    heapq.heapify(ready)
    order = []
    while ready:
        _, n = heapq.heappop(ready)
        order.append(n)
        for m in successors[n]:
            indegree[m] -= 1
            if indegree[m] == 0:
                heapq.heappush(ready, (position[m], m))
    if len(order) < len(names):
        cycle = _find_cycle([n for n in names if indegree[n] > 0], successors)
        raise PipelineError(f"the pipeline graph has a cycle: {' -> '.join(cycle)}; a node cannot depend on itself")
    return order


def _find_cycle(remaining: list[str], successors: dict[str, list[str]]) -> list[str]:
    """A cycle among the nodes Kahn's algorithm could not order: each of them has a predecessor among them,
    so walking predecessors from any of them must revisit a node."""
    inside = set(remaining)
    predecessor = {}
    for a, targets in successors.items():
        for b in targets:
            if a in inside and b in inside:
                predecessor.setdefault(b, a)
    path, seen = [], {}
    node = remaining[0]
    while node not in seen:
        seen[node] = len(path)
        path.append(node)
        node = predecessor[node]
    cycle = path[seen[node]:][::-1]  # walked backwards: reverse into dependency order
    return cycle + [cycle[0]]


def render_dot(dot: str, out: Path) -> Path:
    """Writes `dot` to `out`: Graphviz text for .dot/.gv, else the format of out's suffix (svg, png, pdf)
    through the `dot` program. Raises PipelineError when the program is missing."""
    from m3c.io import atomic_path

    out = Path(out)
    fmt = out.suffix.lstrip(".").lower()
    with atomic_path(out) as tmp:
        if fmt in ("dot", "gv", ""):
            tmp.write_text(dot)
            return out
        program = shutil.which("dot")
        if program is None:
            raise PipelineError(f"writing {out} needs Graphviz's `dot` program (apt-get install graphviz); "
                                "write a .dot file instead")
        done = subprocess.run([program, f"-T{fmt}", "-o", str(tmp)], input=dot.encode(), capture_output=True)
        if done.returncode != 0:
            raise PipelineError(f"dot -T{fmt} failed: {done.stderr.decode(errors='replace').strip()}")
    return out
