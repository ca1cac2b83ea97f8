"""The camera node: the camera intrinsics, given (--intrinsics, or --hfov: the horizontal field of view) or the
default (m3c.io.video.default_intrinsics)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m3c.io.video import default_intrinsics
from m3c.pipeline import InputError, Node, register_node

# Focal lengths of real cameras in units of the image diagonal: 0.2 is a ~136 degree diagonal field of view
# (beyond action-camera fisheye), 10 is ~6 degrees (a long telephoto). --intrinsics outside this range, or with the
# principal point outside the image, are refused unless forced (camera.force_intrinsics, --force-intrinsics).
PLAUSIBLE_FOCAL = (0.2, 10.0)


@register_node
class CameraNode(Node):
    """The camera intrinsics (fx, fy, cx, cy) in pixels: given in the config (intrinsics: --intrinsics; or hfov:
    --hfov, the horizontal field of view in degrees, with square pixels and the principal point at the image
    centre, so one setting fits videos of any size), else default_intrinsics(). Output camera: intrinsics (4,)
    float64, source ("given" or "default")."""

    type_name = "camera"
    level = "frame"
    inputs = ("video",)
    outputs = ("camera",)

    @dataclass
    class Config:
        intrinsics: list[float] | None = None  # fx fy cx cy, pixels
        hfov: float | None = None  # degrees: the horizontal field of view (instead of intrinsics)
        force_intrinsics: bool = False  # use intrinsics outside a physical camera's range anyway (a warning)

    def check(self, ctx) -> None:
        k, hfov = self.config.intrinsics, self.config.hfov
        if k is not None and hfov is not None:
            raise InputError("give the camera's intrinsics or its horizontal field of view (hfov), not both")
        if hfov is not None and not (isinstance(hfov, (int, float)) and 1.0 <= hfov <= 179.0):
            raise InputError(f"hfov must be the horizontal field of view in degrees, 1..179, got {hfov!r} (a phone's "
                             "main camera films about 60-70 degrees wide)")
        if k is not None and (len(k) != 4 or not all(np.isfinite(k)) or k[0] <= 0 or k[1] <= 0):
            raise InputError(f"intrinsics must be 4 numbers fx fy cx cy with fx, fy > 0 (pixels), got {k}")

    def run(self, ctx, inputs):
        video = inputs["video"]
        self.check(ctx)
        if self.config.hfov is not None:
            width, height = video["width"], video["height"]
            focal = 0.5 * width / np.tan(np.radians(self.config.hfov) / 2)
            return {"camera": {"intrinsics": np.array([focal, focal, width / 2, height / 2], dtype=np.float64),
                               "source": "given"}}
        if self.config.intrinsics is None:
            return {"camera": {"intrinsics": default_intrinsics(video["width"], video["height"]),
                               "source": "default"}}
        fx, fy, cx, cy = self.config.intrinsics
        diagonal = float(np.hypot(video["width"], video["height"]))
        low, high = PLAUSIBLE_FOCAL
        problems = [f"{name} = {f:g} px is {f / diagonal:.3g} times the image diagonal ({diagonal:.0f} px); focal "
                    f"lengths of real cameras lie within {low:g}..{high:g} times it ({low * diagonal:.0f}.."
                    f"{high * diagonal:.0f} px)" for name, f in (("fx", fx), ("fy", fy))
                    if not low * diagonal <= f <= high * diagonal]
        if not (0 <= cx <= video["width"] and 0 <= cy <= video["height"]):
            problems.append(f"the principal point ({cx:g}, {cy:g}) lies outside the {video['width']} x "
                            f"{video['height']} image")
        if problems and not self.config.force_intrinsics:
            raise InputError("--intrinsics are not those of a physical camera: " + "; ".join(problems) +
                             ". Check them (pixels, not mm; fx fy cx cy), or use them anyway with "
                             "--force-intrinsics (camera.force_intrinsics=true)")
        for problem in problems:
            ctx.log.warning("%s (used as given: --force-intrinsics)", problem)
        return {"camera": {"intrinsics": np.array([fx, fy, cx, cy], dtype=np.float64), "source": "given"}}
