"""The overlay node: overlay.mp4, the final bodies over the input frames (m3c.viz.scene.overlay_frame)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.camera import WorldCameras
from m3c.io.video import VideoWriter
from m3c.nodes.frames import stream_frames
from m3c.pipeline import FileRef, Node, register_node


@register_node
class OverlayNode(Node):
    """overlay.mp4: the final bodies rendered over the input frames (depth-tested, shaded, one colour per track)."""

    type_name = "overlay"
    level = "output"
    inputs = ("video", "camera", "result")
    outputs = ("video_file",)
    settings = ("body_model",)
    publish = {"video_file": "overlay.mp4"}

    @dataclass
    class Config:
        alpha: float = 0.8  # mesh opacity

    def run(self, ctx, inputs):
        from m3c.viz.scene import BodyFrames, overlay_frame

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        bodies = BodyFrames(model, result["tracks"])
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])
        world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
        playback = video.get("playback_fps", video["fps"])  # as the source plays, slow motion included
        with VideoWriter(ctx.work_path("overlay.mp4"), playback, (video["width"], video["height"])) as writer, \
                ctx.progress("rendering overlay", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                writer.write(overlay_frame(frame, bodies.at(i), model.faces, world_from_cam[i], intrinsics,
                                           self.config.alpha))
                bar.update()
        return {"video_file": FileRef("overlay.mp4")}
