"""The M3C pipeline: an execution graph of cached nodes (seed thesis, section 4.1).

    from m3c.nodes import register_builtin_nodes
    from m3c.pipeline import PipelineConfig, run_pipeline
    register_builtin_nodes()
    report = run_pipeline(PipelineConfig.default(), "out", sources={"video": "clip.mp4"})

The framework imports no domain package: node types (M3C's built-in ones live in m3c.nodes, registered by
register_builtin_nodes(), which the m3c command calls) and loadable settings (register_setting_loader) are
registered by the program that builds the graph. Nodes are configured in YAML (default: m3c/pipeline/default.yaml);
every node's outputs are cached in OUT/cache/<node>/<key>/ so a changed setting re-runs only what depends on it and
an interrupted run resumes.
"""

from m3c.pipeline.config import NodeEntry, PipelineConfig, Settings, default_config_path, parse_override
from m3c.pipeline.graph import Edge, Graph, render_dot, topological_order
from m3c.pipeline.node import (LEVELS, ComponentUnavailable, FileRef, InputError, Needs, Node, NoConfig,
                               PipelineError, node_type, node_types, register_node, register_setting_loader)
from m3c.pipeline.runner import NodeRecord, PipelineUnavailable, RunContext, Runner, RunReport, run_pipeline

__all__ = ["LEVELS", "ComponentUnavailable", "Edge", "FileRef", "Graph", "InputError", "Needs", "Node", "NodeEntry",
           "NoConfig", "NodeRecord", "PipelineConfig", "PipelineError", "PipelineUnavailable", "RunContext",
           "RunReport", "Runner", "Settings", "default_config_path", "node_type", "node_types", "parse_override",
           "register_node", "register_setting_loader", "render_dot", "run_pipeline", "topological_order"]
