"""The local_tracks node: perception's tracks over every frame from their first to their last, gaps filled, short
ones dropped (m3c.motion.local_tracks, thesis 4.1.4)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.motion.local_tracks import local_tracks
from m3c.pipeline import InputError, Node, PipelineError, register_node


@register_node
class LocalTracksNode(Node):
    """One camera-local track per tracked person (m3c.motion.local_tracks.fill_gaps), from the tracks perception
    handed over (after the focal node re-expressed them at its camera).

    Output tracks: {"frame": "camera", "num_frames": T, "tracks": [...]}, each track with track_id, first_frame,
    num_frames n, visible (n,) bool, detection (n,) int (-1 in gaps), keypoints (n, 17, 3) (interpolated in gaps,
    their confidence times gap_confidence), box (n, 4) square boxes, transl (n, 3) and root_orient (n, 3) in the
    camera frame, body_pose (n, 23, 3), betas (B,), contacts (n, 4) or absent.
    """

    type_name = "local_tracks"
    level = "track"
    inputs = ("video", "camera", "tracks")
    outputs = ("tracks",)
    # 2: reads perception's tracks (m3c.perception.handover) instead of per-detection tables
    version = "2"

    @dataclass
    class Config:
        min_visible_frames: int = 5  # shorter tracks are dropped (spurious detections)
        gap_confidence: float = 0.0  # confidence factor of interpolated keypoints (0: the optimizer ignores them)

    def run(self, ctx, inputs):
        video, camera, given = inputs["video"], inputs["camera"], inputs["tracks"]["tracks"]
        try:
            tracks, dropped = local_tracks(given, camera["intrinsics"], self.config.min_visible_frames,
                                           self.config.gap_confidence)
        except ValueError as err:
            raise PipelineError(f"node {self.name!r}: {err}") from None
        if dropped:
            ctx.log.info("dropped %d track(s) seen in fewer than %d frames: ids %s", len(dropped),
                         self.config.min_visible_frames, sorted(dropped))
        if not tracks:
            if dropped:
                seen = ", ".join(f"id {t} in {k} frame{'s' if k != 1 else ''}" for t, k in sorted(dropped.items()))
                frames = len(np.unique(np.concatenate([np.asarray(t["frame"]) for t in given])))
                raise InputError(f"no person was found in the video for long enough: {sum(dropped.values())} "
                                 f"detection(s) in {frames} frame(s), every person track seen in fewer than "
                                 f"{self.config.min_visible_frames} frames ({seen}); to keep short tracks, lower "
                                 "local_tracks.min_visible_frames (e.g. --set local_tracks.min_visible_frames=2)")
            raise InputError("no person was found in the video (no detections)")
        ctx.log.info("%d track(s): %s", len(tracks),
                     ", ".join(f"id {t['track_id']} frames {t['first_frame']}..{t['first_frame'] + t['num_frames'] - 1}"
                               f" ({int(t['visible'].sum())} seen)" for t in tracks))
        return {"tracks": {"frame": "camera", "num_frames": int(video["num_frames"]), "tracks": tracks}}

    def visualize(self, ctx, inputs, outputs, folder):
        try:
            import matplotlib
        except ImportError:
            ctx.log.warning("no track picture: matplotlib is not installed (pip install 'm3c[viz]')")
            return []

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        tracks = outputs["tracks"]["tracks"]
        if not tracks:
            return []
        fig, ax = plt.subplots(figsize=(8, 0.5 + 0.4 * len(tracks)))
        for k, track in enumerate(tracks):
            span = track["first_frame"] + np.arange(track["num_frames"])
            ax.scatter(span[track["visible"]], np.full(track["visible"].sum(), k), s=4, c="tab:blue")
            ax.scatter(span[~track["visible"]], np.full((~track["visible"]).sum(), k), s=4, c="tab:orange")
        ax.set_yticks(range(len(tracks)), [f"id {t['track_id']}" for t in tracks])
        ax.set_xlabel("frame (blue: detected, orange: interpolated)")
        fig.tight_layout()
        path = folder / "tracks.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return [path]
