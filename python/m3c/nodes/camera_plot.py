"""The camera_plot node: camera_trajectory.png (m3c.viz.plots.camera_trajectory_plot)."""

from __future__ import annotations

import numpy as np

from m3c.camera import WorldCameras
from m3c.ground.tracks import track_poses
from m3c.pipeline import ComponentUnavailable, FileRef, Node, register_node


@register_node
class CameraPlotNode(Node):
    """camera_trajectory.png: top view of the camera path and the people's paths; camera height over time."""

    type_name = "camera_plot"
    level = "output"
    inputs = ("video", "result")
    outputs = ("plot",)
    settings = ("body_model",)
    publish = {"plot": "camera_trajectory.png"}

    def check(self, ctx) -> None:
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise ComponentUnavailable(self.name, "matplotlib", "install the viz extra (pip install 'm3c[viz]'), "
                                       "or remove the camera_plot node from the pipeline config")

    def run(self, ctx, inputs):
        from m3c.viz.plots import camera_trajectory_plot

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        people = [(int(t["track_id"]), model.joints(track_poses(t), np.asarray(t["betas"]), np.asarray(t["transl"]))[:, 0])
                  for t in result["tracks"]]
        scale = f"{result['camera_scale']:.3f} m per odometry unit"
        cameras = WorldCameras(**result["cameras"]).world_from_cam()
        camera_trajectory_plot(ctx.work_path("camera_trajectory.png"), cameras, float(video["fps"]), people,
                               f"{video['name']}: camera trajectory ({scale})")
        return {"plot": FileRef("camera_trajectory.png")}
