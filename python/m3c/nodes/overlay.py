"""The overlay node: overlay.mp4, the final bodies over the input frames (m3c.viz.scene.overlay_frame), with
the fitted hands' fingers drawn over them (m3c.viz.scene.draw_hands) when the hands node found any."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.camera import WorldCameras
from m3c.io.video import VideoWriter
from m3c.nodes.frames import stream_frames
from m3c.pipeline import FileRef, Node, register_node


@register_node
class OverlayNode(Node):
    """overlay.mp4: the final bodies rendered over the input frames (depth-tested, shaded, one colour per
    track), and the fitted fingers as lines between the 21 hand points."""

    version = "2"  # 2: hands
    type_name = "overlay"
    level = "output"
    inputs = ("video", "camera", "result", "hands")
    optional_inputs = ("hands",)
    outputs = ("video_file",)
    settings = ("body_model",)
    publish = {"video_file": "overlay.mp4"}

    @dataclass
    class Config:
        alpha: float = 0.8  # mesh opacity

    def run(self, ctx, inputs):
        from m3c.viz.scene import BodyFrames, draw_hands, overlay_frame

        video, result = inputs["video"], inputs["result"]
        model = ctx.loaded("body_model")
        tracks, hands = tracks_with_hands(model, result["tracks"], inputs.get("hands"))
        bodies = BodyFrames(model, tracks)
        intrinsics = np.asarray(inputs["camera"]["intrinsics"])
        world_from_cam = WorldCameras(**result["cameras"]).world_from_cam()
        playback = video.get("playback_fps", video["fps"])  # as the source plays, slow motion included
        with VideoWriter(ctx.work_path("overlay.mp4"), playback, (video["width"], video["height"])) as writer, \
                ctx.progress("rendering overlay", video["num_frames"]) as bar:
            for i, frame in stream_frames(ctx, video):
                image = overlay_frame(frame, bodies.at(i), model.faces, world_from_cam[i], intrinsics,
                                      self.config.alpha)
                writer.write(draw_hands(image, hands_at(hands, i), world_from_cam[i], intrinsics))
                bar.update()
        return {"video_file": FileRef("overlay.mp4")}


def tracks_with_hands(model, tracks: list[dict], hands: dict | None) -> tuple[list[dict], list[tuple]]:
    """The tracks with the hand fit's wrists, and per track with hands (first_frame, world points n x 2 x 21 x
    3, track id)."""
    from m3c.ground.tracks import track_poses
    from m3c.nodes.hands import corrected_body_pose
    from m3c.nodes.results import world_hand_keypoints

    by_id = {t["track_id"]: t for t in (hands or {}).get("tracks", [])}
    out, points = [], []
    for track in tracks:
        hand = by_id.get(track["track_id"])
        if hand is None:
            out.append(track)
            continue
        track = {**track, "body_pose": corrected_body_pose(track["body_pose"], hand["wrist_correction"])}
        out.append(track)
        world = world_hand_keypoints(model, track_poses(track), np.asarray(track["betas"], dtype=np.float64),
                                     np.asarray(track["transl"], dtype=np.float64), hand["hand_pose"])
        points.append((int(track["first_frame"]), world, int(track["track_id"])))
    return out, points


def hands_at(hands: list[tuple], frame: int) -> list[tuple[np.ndarray, int]]:
    """(world points 2 x 21 x 3, track id) of the tracks with hands at a frame."""
    return [(world[frame - first], tid) for first, world, tid in hands if 0 <= frame - first < len(world)]
