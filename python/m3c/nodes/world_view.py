"""The world_view node: world.mp4, the scene from a virtual camera: by default a chase camera framed on the people
with their footprints and paths (m3c.viz.chase), or the fixed whole-scene overview (m3c.viz.scene.WorldView)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.body.joint_names import CONTACT_JOINTS
from m3c.camera import WorldCameras
from m3c.ground.tracks import track_poses
from m3c.io.video import VideoWriter
from m3c.pipeline import FileRef, InputError, Node, register_node

VIEWS = ("chase", "overview")


@register_node
class WorldViewNode(Node):
    """world.mp4. view "chase": a camera that follows the people (about half the frame high, a raised three-quarter
    view, smoothed so it never cuts), the footprints of planted feet (they stay), the pelvis paths, a ground grid in
    metres with a scale bar, the frame's time and the whole scene from above as an inset with the video camera's
    path and frustum. view "overview": ground, people and the video camera from one fixed virtual camera.
    beside_video: the input video at the left of the world view, in one file."""

    # 2: the chase view, beside_video
    version = "2"
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
        view: str = "chase"  # "chase" (framed on the people) or "overview" (the whole scene, fixed)
        beside_video: bool = False  # the input video and the world view side by side in world.mp4
        yaw: float = 35.0  # overview: degrees about the up axis, from behind the first camera
        elevation: float = 30.0  # overview: degrees above the ground

    def check(self, ctx) -> None:
        if self.config.view not in VIEWS:
            raise InputError(f"world_view.view must be one of {', '.join(VIEWS)}, got {self.config.view!r}")
        if self.config.width < 64 or self.config.height < 64:
            raise InputError(f"world_view.width and height must be at least 64 pixels, got "
                             f"{self.config.width} x {self.config.height}")

    def run(self, ctx, inputs):
        from m3c.viz.scene import BodyFrames

        self.check(ctx)
        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
        if inputs["ground"]["up_source"] == "ground":
            ground_height = 0.0
        else:  # no ground found: draw one under the lowest foot
            lows = [model.joints(track_poses(t), np.asarray(t["betas"]), np.asarray(t["transl"]))
                    [:, list(CONTACT_JOINTS), 1].min() for t in result["tracks"]]
            ground_height = float(min(lows)) - 0.05 if lows else 0.0
        draw = self._chase(model, video, inputs, result, world_from_cam, ground_height) \
            if self.config.view == "chase" else self._overview(inputs, video, result, world_from_cam, ground_height)
        bodies = BodyFrames(model, result["tracks"])
        T = int(video["num_frames"])
        size = (self.config.width, self.config.height)
        frames = self._video_frames(ctx, video) if self.config.beside_video else None
        if frames is not None:
            scaled_width = int(round(video["width"] * self.config.height / video["height"])) // 2 * 2
            size = (scaled_width + self.config.width, self.config.height)
        playback = video.get("playback_fps", video["fps"])  # as the source plays, slow motion included
        with VideoWriter(ctx.work_path("world.mp4"), playback, size) as writer, \
                ctx.progress("rendering world view", T) as bar:
            for i in range(T):
                image = draw(i, bodies.at(i), model.faces)
                if frames is not None:
                    import cv2

                    _, frame = next(frames)
                    frame = cv2.resize(frame, (scaled_width, self.config.height), interpolation=cv2.INTER_AREA)
                    image = np.hstack([frame, image])
                writer.write(image)
                bar.update()
        return {"video_file": FileRef("world.mp4")}

    @staticmethod
    def _video_frames(ctx, video):
        from m3c.nodes.frames import stream_frames

        return iter(stream_frames(ctx, video))

    def _chase(self, model, video, inputs, result, world_from_cam, ground_height):
        from m3c.motion.config import OptimizerConfig
        from m3c.viz.chase import ChaseFrames, ChaseView, track_motions

        # Planted as the optimizer holds them (its contact threshold): the footprints show its contacts.
        motions = track_motions(model, result["tracks"], OptimizerConfig.default().contact_threshold)
        T = int(video["num_frames"])
        people = [[] for _ in range(T)]
        for m in motions:
            for k in range(m.num_frames):
                if 0 <= m.first_frame + k < T:
                    people[m.first_frame + k].append(m.pelvis[k])
        people = [np.array(p).reshape(-1, 3) for p in people]
        view = ChaseView(people, world_from_cam[:, :3, 3], ground_height, float(video["fps"]), self.config.width,
                         self.config.height)
        times = np.asarray(video["times"], dtype=np.float64)
        frames = ChaseFrames(view, motions, world_from_cam, np.asarray(inputs["camera"]["intrinsics"]),
                             (video["width"], video["height"]), times)
        return frames.frame

    def _overview(self, inputs, video, result, world_from_cam, ground_height):
        from m3c.viz.scene import WorldView

        roots = [np.asarray(t["transl"]) for t in result["tracks"]]
        people = np.concatenate(roots) if roots else np.zeros((0, 3))
        view = WorldView(people, world_from_cam[:, :3, 3], ground_height, self.config.width, self.config.height,
                         self.config.yaw, self.config.elevation)
        depth = 0.15 * view.tile * 4
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])

        def draw(i, bodies, faces):
            return view.frame(bodies, faces, world_from_cam[:i + 1, :3, 3], world_from_cam[i], intrinsics,
                              (video["width"], video["height"]), depth)
        return draw
