"""The scale node: metres per visual-odometry unit (math: m3c.motion.scale.estimate_camera_scale)."""

from __future__ import annotations

from dataclasses import dataclass

from m3c.motion.scale import estimate_camera_scale
from m3c.pipeline import Node, PipelineError, register_node
from m3c.vo.scale import ScaleEstimate


@register_node
class ScaleNode(Node):
    """The metric size of one visual-odometry translation unit: M3C's one scale estimator (m3c.vo.scale, whose
    docstring states the model), fusing every observation that carries scale with its uncertainty.
    Output scale: value, sigma (standard deviation of log(value); None when nothing measured it), source
    ("given", "static camera", "default", or the sources used, e.g. "planted feet+ground"), consistent,
    observations (per source: value, sigma, frames, reason), ground_plane (the odometry map's ground, VO frame and
    units, that the ground source measured against; None without one)."""

    # 2: per-person ground source, the feet's model error, the map's ground plane in the output;
    # 3: the planted-feet source on the ground contacts (the feet surely on the ground); 4: m3c.vo.scale's
    # random-effects fusion and the ground source's camera-height check (a cached scale is the old fusion's);
    # 5: the gait source (the people's steps against their legs), a source that disagrees with all the others
    # while they agree set aside; 6: only the people near the camera measure it (scale_subjects), and the ground
    # source needs map points where they stand (floor_support)
    version = "6"
    type_name = "scale"
    level = "track"
    inputs = ("tracks", "cameras", "depth", "camera", "video")
    optional_inputs = ("depth", "camera", "video")
    outputs = ("scale",)
    settings = ("body_model",)

    @dataclass
    class Config:
        value: float | None = None  # fixed metres per VO unit; None = estimate
        contact_threshold: float = 0.5

    def run(self, ctx, inputs):
        cameras = inputs["cameras"]
        if self.config.value is not None:
            if not self.config.value > 0:
                raise PipelineError(f"scale.value must be > 0, got {self.config.value}")
            return {"scale": ScaleEstimate(float(self.config.value), 0.0, "given").to_dict()}
        if cameras["static"] or cameras.get("rotation_only"):  # no translation: any scale gives the same world
            return {"scale": ScaleEstimate(1.0, None, "static camera" if cameras["static"] else "rotation only")
                    .to_dict()}
        camera = inputs.get("camera")
        estimate = estimate_camera_scale(ctx.loaded("body_model"), inputs["tracks"]["tracks"], cameras,
                                         self.config.contact_threshold, inputs.get("depth"),
                                         camera["intrinsics"] if camera is not None else None, ctx.log,
                                         fps=float(inputs["video"]["fps"]) if inputs.get("video") else None)
        if estimate.sigma is None:
            ctx.log.warning("nothing measured the camera's scale; starting from 1 m per VO unit")
        else:
            ctx.log.info("camera scale %.4g m per VO unit (+-%.1f%%) from %s", estimate.value,
                         100 * estimate.sigma, estimate.source)
        return {"scale": estimate.to_dict()}
