"""Local human tracks (thesis 4.1.4, "Local Human Tracks Creation").

Detections are gathered by track id into one track per person spanning its first to last detection. Frames in
between without a detection are filled: keypoints, translation, contacts and boxes linearly; root orientation
and every body joint rotation by spherical linear interpolation on SO(3) (as SLAHMR). Betas are averaged over
the detected frames (the optimizer keeps one shape per person).

Camera: a body estimated on a patch comes with the patch's weak-perspective camera (s, tx, ty): a body point X
projects to patch coordinates s * (X_xy + (tx, ty)) in [-1, 1]. crop_to_full_camera turns it into a translation
in the full image's perspective camera (CLIFF's conversion, in m3c.perception.boxes), so every person sits in one
camera frame at its own place, and the tracks keep their positions relative to each other (thesis Fig. 4.9) instead
of all being centred in front of the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.motion.interpolate import interpolate_linear, interpolate_rotations
from m3c.nodes.records import table_length
from m3c.perception.boxes import crop_to_full_camera
from m3c.pipeline import InputError, Node, PipelineError, register_node


@register_node
class LocalTracksNode(Node):
    """One camera-local track per tracked person (see the module docstring).

    Output tracks: {"frame": "camera", "num_frames": T, "tracks": [...]}, each track with track_id, first_frame,
    num_frames n, visible (n,) bool, detection (n,) int (-1 in gaps), keypoints (n, 17, 3) (interpolated in gaps,
    their confidence times gap_confidence), box (n, 4) square boxes, transl (n, 3) and root_orient (n, 3) in the
    camera frame, body_pose (n, 23, 3), betas (B,), contacts (n, 4) or absent.
    """

    type_name = "local_tracks"
    level = "track"
    inputs = ("video", "camera", "detections", "boxes", "keypoints", "body", "tracking", "contacts")
    optional_inputs = ("contacts",)
    outputs = ("tracks",)

    @dataclass
    class Config:
        min_visible_frames: int = 5  # shorter tracks are dropped (spurious detections)
        gap_confidence: float = 0.0  # confidence factor of interpolated keypoints (0: the optimizer ignores them)

    def run(self, ctx, inputs):
        video, camera = inputs["video"], inputs["camera"]
        detections, boxes, keypoints = inputs["detections"], inputs["boxes"], inputs["keypoints"]
        body, tracking, contacts = inputs["body"], inputs["tracking"], inputs["contacts"]
        n = table_length(detections, ("frame", "score"), "detections")
        for name, table, column in (("boxes", boxes, "square"), ("keypoints", keypoints, "keypoints"),
                                    ("body", body, "pose"), ("tracking", tracking, "track_id")):
            if len(table[column]) != n:
                raise PipelineError(f"{name}.{column} has {len(table[column])} rows, detections {n}")
        if "transl" in body:
            transl = np.asarray(body["transl"], dtype=np.float64)
        else:
            transl = crop_to_full_camera(body["crop_cam"], boxes["square"], camera["intrinsics"])
        track_ids = np.asarray(tracking["track_id"])
        tracks, dropped = [], {}  # dropped: track id -> frames seen
        for track_id in np.unique(track_ids[track_ids >= 0]):
            rows = np.flatnonzero(track_ids == track_id)
            # One detection per frame: the best-scoring one.
            rows = rows[np.lexsort((-detections["score"][rows], detections["frame"][rows]))]
            rows = rows[np.r_[True, np.diff(detections["frame"][rows]) > 0]]
            if len(rows) < self.config.min_visible_frames:
                dropped[int(track_id)] = len(rows)
                continue
            tracks.append(self._gather(int(track_id), rows, detections, boxes, keypoints, body, transl, contacts))
        if dropped:
            ctx.log.info("dropped %d track(s) seen in fewer than %d frames: ids %s", len(dropped),
                         self.config.min_visible_frames, sorted(dropped))
        if not tracks:
            seen = ", ".join(f"id {t} in {k} frame{'s' if k != 1 else ''}" for t, k in sorted(dropped.items()))
            frames = len(np.unique(detections["frame"])) if n else 0
            if dropped:
                raise InputError(f"no person was found in the video for long enough: {n} detection(s) in {frames} "
                                 f"frame(s), every person track seen in fewer than "
                                 f"{self.config.min_visible_frames} frames ({seen}); to keep short tracks, lower "
                                 "local_tracks.min_visible_frames (e.g. --set local_tracks.min_visible_frames=2)")
            if n:
                raise InputError(f"no person was found in the video: {n} detection(s) in {frames} frame(s), none "
                                 "assigned to a person track")
            raise InputError("no person was found in the video (no detections)")
        ctx.log.info("%d track(s): %s", len(tracks),
                     ", ".join(f"id {t['track_id']} frames {t['first_frame']}..{t['first_frame'] + t['num_frames'] - 1}"
                               f" ({int(t['visible'].sum())} seen)" for t in tracks))
        return {"tracks": {"frame": "camera", "num_frames": int(video["num_frames"]), "tracks": tracks}}

    def _gather(self, track_id, rows, detections, boxes, keypoints, body, transl, contacts) -> dict:
        frames = detections["frame"][rows].astype(np.int64)
        first, last = int(frames[0]), int(frames[-1])
        span = np.arange(first, last + 1)
        visible = np.isin(span, frames)
        detection = np.full(len(span), -1, dtype=np.int64)
        detection[frames - first] = rows
        t = frames.astype(np.float64)
        kp = interpolate_linear(t, keypoints["keypoints"][rows], span)
        kp[~visible, :, 2] *= self.config.gap_confidence
        kp[visible] = keypoints["keypoints"][rows]  # exact where seen
        pose = np.asarray(body["pose"], dtype=np.float64)[rows]
        rot = interpolate_rotations(t, pose, span)
        rot[visible] = pose
        track = {
            "track_id": track_id, "first_frame": first, "num_frames": len(span), "visible": visible,
            "detection": detection,
            "keypoints": kp.astype(np.float32),
            "box": interpolate_linear(t, boxes["square"][rows], span).astype(np.float32),
            "transl": interpolate_linear(t, transl[rows], span),
            "root_orient": rot[:, 0],
            "body_pose": rot[:, 1:],
            "betas": np.asarray(body["betas"], dtype=np.float64)[rows].mean(axis=0),
        }
        if contacts is not None:
            track["contacts"] = np.clip(interpolate_linear(t, contacts["joint_contacts"][rows], span), 0, 1)
            if "ground_contacts" in contacts:
                track["ground_contacts"] = np.clip(interpolate_linear(t, contacts["ground_contacts"][rows], span),
                                                   0, 1)
        return track

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
