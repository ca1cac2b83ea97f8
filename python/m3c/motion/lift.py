"""Camera-local tracks into the world frame (thesis 4.1.4, world lift): each frame's camera-local body moved by
its camera, or, with WHAM's network (m3c.motion.wham_lift), the root trajectory from WHAM's decoder."""

from __future__ import annotations

import numpy as np

from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.ground.tracks import track_frames


def lift_tracks(model, tracks: list[dict], world_from_cam: np.ndarray, ground_tracks: list[dict],
                trajectory=None) -> list[dict]:
    """Every camera-frame track in the world.

    world_from_cam: (T, 4, 4) metric cameras in the world; ground_tracks: the ground's per-track planes (normal,
    offset, valid), copied onto a track when valid in all its frames; trajectory: None (the camera lift), or a
    function (track, root_world, transl_world) -> (root_world, transl_world) that replaces the camera lift's
    root orientation and translation (WHAM's, see m3c.motion.wham_lift.wham_trajectory).
    Returns per track: track_id, first_frame, num_frames, visible, keypoints, transl, root_orient, body_pose,
    betas, contacts?, ground_contacts?, ground_normal?, ground_offset?.
    """
    out = []
    for k, track in enumerate(tracks):
        frames = track_frames(track)
        j0 = rest_root_joint(model, track["betas"])
        root, transl = transform_smpl(world_from_cam[frames], track["root_orient"], track["transl"], j0)
        if trajectory is not None:
            root, transl = trajectory(track, root, transl)
        world = {key: track[key] for key in ("track_id", "first_frame", "num_frames", "visible",
                                             "keypoints", "body_pose", "betas")}
        world.update(root_orient=root, transl=transl)
        for key in ("contacts", "ground_contacts"):
            if key in track:
                world[key] = track[key]
        if ground_tracks and ground_tracks[k]["valid"].all():
            world["ground_normal"] = ground_tracks[k]["normal"]
            world["ground_offset"] = ground_tracks[k]["offset"]
        out.append(world)
    return out
