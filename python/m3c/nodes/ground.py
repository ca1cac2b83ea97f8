"""The ground node: the ground planes and the gravity-aligned world frame (math: m3c.ground.world_frame)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from m3c.ground import GroundParams
from m3c.ground.world_frame import estimate_ground
from m3c.pipeline import Node, register_node
from m3c.vo.focal import camera_focal_log_sigma


@register_node
class GroundNode(Node):
    """The ground and the gravity-aligned world frame (thesis 4.1.3, "Ground Estimation"): m3c.ground.world_frame.
    estimate_ground at the scale node's scale, on the odometry map's ground plane that the scale measured against
    when the people's contacts lie on it (map_ground), the contacts' ground tilted as the scene's vertical edges
    say where the focal node measured them (camera: its output; scene_up) (planes: shared, SLAHMR's single floor,
    the default; or per_person, the thesis's planes, each frame pooling the contacts of `window` frames around
    it).

    Output ground: world_from_vo (4, 4) (metric VO frame at the estimated scale -> world), cameras (the fields of
    m3c.camera.WorldCameras: the VO cameras in the world at the estimated scale, offset 0), up_source
    ("ground" or "camera"), plane (normal (3,), offset) the dominant plane in the world (y = 0 when found),
    tracks: per track normal (n, 3), offset (n,) in the world, observed (n,), valid (n,).
    Output scale: the scale node's, passed on (the ground is fitted at that scale).
    """

    # 2: the cameras in the world (WorldCameras); 3: the map's ground plane when the contacts agree; 4: the
    # contacts' ground fitted along the camera rays, with the people's upright direction as the tilt's prior;
    # 5: the scene's vertical edges as that prior where the focal node measured them (scene_up); 6: tilt_prior;
    # 7: the scene's up wherever its frames agree (not only where its lines gave the focal length), a frame
    #    another family of edges out, its forward sigma from the focal length's uncertainty
    version = "7"
    type_name = "ground"
    level = "smpl"
    inputs = ("tracks", "cameras", "scale", "camera")
    optional_inputs = ("camera",)
    outputs = ("ground", "scale")
    settings = ("body_model",)

    @dataclass
    class Config:
        planes: Literal["shared", "per_person"] = "shared"  # one ground for all (SLAHMR), or the thesis's
        contact_threshold: float = 0.5
        window: int = 15  # frames each side whose contacts join a frame's (0 = per frame, as the thesis)
        max_tilt: float = 10.0  # degrees: a person's plane tilted more from the dominant ground is not kept
        # The plane fits' settings (m3c.ground.GroundParams, whose defaults are the C++ core's).
        eps: float = GroundParams.eps
        min_samples: int = GroundParams.min_samples
        robust: bool = GroundParams.robust
        inlier_threshold: float = GroundParams.inlier_threshold
        min_support: int = GroundParams.min_support
        max_iterations: int = GroundParams.max_iterations
        confidence: float = GroundParams.confidence
        seed: int = GroundParams.seed
        max_distance: float = GroundParams.max_distance
        fill: Literal["hold", "linear"] = GroundParams.fill
        level_with_body_up: bool = True  # the contacts' ground's tilt prior: the people's upright (else the camera's)
        map_ground: bool = True  # the odometry map's ground plane (the scale's) when the contacts lie on it
        scene_up: bool = True  # the scene's vertical edges (the focal node's scene record) as the tilt's prior

    def params(self) -> GroundParams:
        c = asdict(self.config)
        for key in ("planes", "contact_threshold", "window", "max_tilt", "level_with_body_up", "map_ground",
                    "scene_up"):
            c.pop(key)
        return GroundParams(**c)

    def run(self, ctx, inputs):
        scale = dict(inputs["scale"])
        camera = inputs.get("camera") or {}
        ground = estimate_ground(ctx.loaded("body_model"), inputs["tracks"]["tracks"],
                                 np.asarray(inputs["cameras"]["world_from_cam"], dtype=np.float64), scale["value"],
                                 self.params(), planes=self.config.planes,
                                 contact_threshold=self.config.contact_threshold, window=self.config.window,
                                 max_tilt=self.config.max_tilt, level=self.config.level_with_body_up, log=ctx.log,
                                 map_plane=scale.get("ground_plane") if self.config.map_ground else None,
                                 scene=camera.get("scene") if self.config.scene_up else None,
                                 focal_log_sigma=camera_focal_log_sigma(camera))
        ground["cameras"] = ground["cameras"].as_dict()
        return {"ground": ground, "scale": scale}
