"""The depth node: relative depth per frame for visual odometry (thesis: optional). No monocular depth estimator
is built in, so the node is off (enabled: false) and says so when turned on."""

from __future__ import annotations

from dataclasses import dataclass

from m3c.pipeline import ComponentUnavailable, Node, register_node


@register_node
class DepthNode(Node):
    """Relative depth per frame, used to initialise visual odometry and, when metric, by the scale node. Off by
    default; output depth: {available: False} (the vo and scale nodes then run without depth)."""

    type_name = "depth"
    level = "frame"
    inputs = ("video",)
    outputs = ("depth",)

    @dataclass
    class Config:
        enabled: bool = False

    def check(self, ctx) -> None:
        if self.config.enabled:
            raise ComponentUnavailable(self.name, "monocular depth", "no depth estimator is part of this build; "
                                       "set depth.enabled: false (the default) to run visual odometry without depth")

    def run(self, ctx, inputs):
        return {"depth": {"available": False}}
