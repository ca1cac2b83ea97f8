"""The lean node: perception's people re-fitted to lean as the scene's vertical says (m3c.perception.lean)."""

from __future__ import annotations

import numpy as np

from m3c.ground.world_frame import scene_up_prior
from m3c.perception.lean import LeanConfig, releaned_track
from m3c.pipeline import InputError, Node, register_node
from m3c.vo.focal import camera_focal_log_sigma


@register_node
class LeanNode(Node):
    """Each track's camera-local bodies that lean away from the camera re-fitted to lean as the scene's vertical
    edges say an upright person does (m3c.perception.lean.releaned_track), where the focal node measured those edges and they
    agree over its sampled frames (m3c.ground.world_frame.scene_up_prior, at the odometry's camera rotations):
    a monocular fit leans people too little towards a camera looking down, and places them too far. Without the
    scene's up (or with enabled false) the tracks pass through unchanged.

    Output tracks: the focal node's tracks ({"tracks": [...]}, m3c.perception.handover), re-fitted where they
    leaned, plus "lean": per track its record (lean_before, lean_after, turn in degrees, refit, depth_ratio,
    reprojection_px or the reason it was left alone) and "up_source" ("scene" or None).
    Config: m3c.perception.lean.LeanConfig (enabled, min_lean, max_lean, max_up_sigma, keypoints3d_weight,
    restart_gap)."""

    type_name = "lean"
    level = "smpl"
    # bump when m3c.perception.lean's behaviour changes (its code is not part of this class's hash); 2: its re-fit
    # turns a warm fit that ends turned far from the 3D torso back (cpp/fit max_turn_from_3d_deg); 3: and re-solves
    # a limb far from the 3D (max_limb_from_3d_m)
    version = "3"
    inputs = ("tracks", "camera", "cameras")
    outputs = ("tracks",)
    settings = ("body_model",)

    Config = LeanConfig

    def check(self, ctx) -> None:
        try:
            self.config.validate()
        except ValueError as err:
            raise InputError(f"node {self.name!r}: {err}") from None

    def run(self, ctx, inputs):
        given, camera = inputs["tracks"], inputs["camera"]
        vo = np.asarray(inputs["cameras"]["world_from_cam"], dtype=np.float64)
        passed = dict(given, lean=[], up_source=None)
        if not self.config.enabled:
            return {"tracks": passed}
        prior = scene_up_prior(camera.get("scene"), vo, camera_focal_log_sigma(camera), ctx.log)
        if prior is None:
            ctx.log.info("people's lean: no scene up direction (vertical edges agreeing over the sampled frames); "
                         "the bodies stay as fitted")
            return {"tracks": passed}
        up_vo, _, forward = prior
        if forward > self.config.max_up_sigma:
            ctx.log.info("people's lean: the scene's up is known to %.1f degrees forwards (%.1f allowed: the focal "
                         "length's uncertainty); the bodies stay as fitted", forward, self.config.max_up_sigma)
            return {"tracks": passed}
        model = ctx.loaded("body_model")
        tracks, records = [], []
        for track in given["tracks"]:
            frames = np.asarray(track["frame"], dtype=np.int64)
            up = np.einsum("nji,j->ni", vo[frames, :3, :3], up_vo)  # the up direction in each frame's camera
            track, record = releaned_track(model, track, up, camera["intrinsics"], self.config)
            record = dict(record, track_id=int(track["track_id"]))
            tracks.append(track)
            records.append(record)
            if record["refit"]:
                ctx.log.info("people's lean: track %d leaned %+.1f degrees towards the camera, re-fitted to %+.1f "
                             "(depth x%.3f, %.1f px)", record["track_id"], record["lean_before"],
                             record["lean_after"], record["depth_ratio"], record["reprojection_px"] or np.nan)
        return {"tracks": dict(given, tracks=tracks, lean=records, up_source="scene")}
