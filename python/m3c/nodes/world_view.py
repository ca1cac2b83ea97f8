"""The world_view node: world.mp4, the scene from a fixed virtual camera (m3c.viz.scene.WorldView)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.body.joint_names import CONTACT_JOINTS
from m3c.camera import WorldCameras
from m3c.ground.tracks import track_poses
from m3c.io.video import VideoWriter
from m3c.pipeline import FileRef, Node, register_node


@register_node
class WorldViewNode(Node):
    """world.mp4: ground, people and the video camera (frustum and path so far) seen from a fixed virtual camera."""

    type_name = "world_view"
    level = "output"
    inputs = ("video", "camera", "ground", "result")
    outputs = ("video_file",)
    settings = ("body_model",)
    publish = {"video_file": "world.mp4"}

    @dataclass
    class Config:
        width: int = 960
        height: int = 540
        yaw: float = 35.0  # degrees about the up axis, from behind the first camera
        elevation: float = 30.0  # degrees above the ground

    def run(self, ctx, inputs):
        from m3c.viz.scene import BodyFrames, WorldView

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
        roots = [np.asarray(t["transl"]) for t in result["tracks"]]
        people = np.concatenate(roots) if roots else np.zeros((0, 3))
        if inputs["ground"]["up_source"] == "ground":
            ground_height = 0.0
        else:  # no ground found: draw one under the lowest foot
            lows = [model.joints(track_poses(t), np.asarray(t["betas"]), np.asarray(t["transl"]))
                    [:, list(CONTACT_JOINTS), 1].min() for t in result["tracks"]]
            ground_height = float(min(lows)) - 0.05 if lows else 0.0
        view = WorldView(people, world_from_cam[:, :3, 3], ground_height, self.config.width, self.config.height,
                         self.config.yaw, self.config.elevation)
        bodies = BodyFrames(model, result["tracks"])
        depth = 0.15 * view.tile * 4
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])
        playback = video.get("playback_fps", video["fps"])  # as the source plays, slow motion included
        with VideoWriter(ctx.work_path("world.mp4"), playback, (self.config.width, self.config.height)) as writer, \
                ctx.progress("rendering world view", video["num_frames"]) as bar:
            for i in range(int(video["num_frames"])):
                writer.write(view.frame(bodies.at(i), model.faces, world_from_cam[:i + 1, :3, 3], world_from_cam[i],
                                        intrinsics, (video["width"], video["height"]), depth))
                bar.update()
        return {"video_file": FileRef("world.mp4")}
