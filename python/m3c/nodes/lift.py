"""The lift node: every track in the world frame (math: m3c.motion.lift, m3c.motion.wham_lift)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

from m3c.camera import WorldCameras
from m3c.motion.lift import lift_tracks
from m3c.pipeline import ComponentUnavailable, Node, register_node


@register_node
class LiftNode(Node):
    """Every track in the world frame (thesis 4.1.4, world lift).

    method camera: each frame's camera-local body moved by its camera (the ground node's cameras in the world, at
    the estimated scale). method wham: root orientation and translation from WHAM's trajectory decoder (its official
    checkpoint, see m3c.models.load_wham; without one, M3C's own shipped world regressor,
    m3c.models.weights.shipped_regressor_path), body pose and shape from the local tracks. auto: wham when the
    official checkpoint is found, else camera.

    Output world: tracks (per track: track_id, first_frame, num_frames, visible, keypoints, transl, root_orient,
    body_pose, betas, contacts?, ground_normal?, ground_offset?), cameras (the ground node's WorldCameras fields:
    the cameras the tracks were lifted with; their scale is the optimizer's initial scale), scale_sigma (the scale
    estimator's, None when nothing measured it), scale_source, static, method.
    """

    version = "3"  # 2: cameras (WorldCameras) replace world_from_cam in VO units and initial_scale; 3: ground_contacts
    type_name = "lift"
    level = "track"
    inputs = ("video", "camera", "tracks", "cameras", "scale", "ground")
    outputs = ("world",)
    settings = ("body_model", "models_dir")

    @dataclass
    class Config:
        method: Literal["auto", "camera", "wham"] = "auto"
        checkpoint: str | None = None  # WHAM checkpoint file; None = $M3C_MODELS/wham/...

    def _wham_checkpoint(self, ctx):
        """The network file: the official checkpoint (config.checkpoint, else the models folder's); for method
        wham without either, the shipped regressor. None: auto without the official file (the camera lift)."""
        from m3c.models.checkpoint import locate
        from m3c.models.wham import WHAM_SOURCE

        explicit = self.config.checkpoint is not None
        path = locate(self.config.checkpoint, ctx.models_dir(), WHAM_SOURCE, self.config.method == "wham"
                      and explicit)
        if path is None and self.config.method == "wham":
            from m3c.models.weights import shipped_regressor_path

            try:
                return shipped_regressor_path()
            except FileNotFoundError:  # an install without it: the official file's message says what to get
                return locate(None, ctx.models_dir(), WHAM_SOURCE, True)
        return path

    @staticmethod
    def _is_shipped_regressor(path) -> bool:
        from m3c.models.weights import weights_dir

        return path is not None and path.resolve() == (weights_dir() / "regressor.pt").resolve()

    def key_config(self, ctx):
        from m3c.models.checkpoint import CheckpointNotFoundError
        from m3c.pipeline.cache import file_digest

        config = asdict(self.config)
        if self.config.method != "camera":
            try:
                path = self._wham_checkpoint(ctx)
            except CheckpointNotFoundError:  # method wham without its file: check() reports it
                path = None
            config["checkpoint_digest"] = file_digest(path) if path is not None else None
        return config

    def check(self, ctx) -> None:
        from m3c.models.checkpoint import CheckpointNotFoundError

        if self.config.method == "wham":
            try:
                self._wham_checkpoint(ctx)
            except CheckpointNotFoundError as err:
                raise ComponentUnavailable(self.name, "WHAM's checkpoint", str(err)) from None

    def load(self, ctx) -> None:
        self._lifter = None
        path = self._wham_checkpoint(ctx) if self.config.method != "camera" else None
        if path is not None and self._is_shipped_regressor(path):
            from m3c.training.regressor import load_regressor

            self._lifter = load_regressor(path).to(ctx.device)
            ctx.log.info("WHAM lift with M3C's regressor %s on %s", path, ctx.device)
        elif path is not None:
            from m3c.models import load_wham

            self._lifter = load_wham(path).to(ctx.device)
            ctx.log.info("WHAM lift with %s on %s", path, ctx.device)

    def unload(self) -> None:
        self._lifter = None

    def run(self, ctx, inputs):
        model = ctx.loaded("body_model")
        cameras = WorldCameras(**inputs["ground"]["cameras"])
        metric = cameras.world_from_cam()
        lifter = getattr(self, "_lifter", None)
        trajectory = None
        if lifter is not None:
            from m3c.motion.wham_lift import wham_trajectory

            def wham(track, root, transl):
                return wham_trajectory(lifter, model, track, metric, root, transl, inputs["video"],
                                       inputs["camera"]["intrinsics"])
            trajectory = wham
        tracks = lift_tracks(model, inputs["tracks"]["tracks"], metric, inputs["ground"]["tracks"], trajectory)
        return {"world": {"tracks": tracks, "cameras": cameras.as_dict(),
                          "scale_sigma": inputs["scale"].get("sigma"),
                          "scale_source": str(inputs["scale"].get("source", "")),
                          "static": bool(inputs["cameras"]["static"]),
                          "method": "wham" if lifter is not None else "camera"}}
