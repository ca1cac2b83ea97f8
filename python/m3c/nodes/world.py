"""From camera-local tracks to the world frame (thesis 4.1.3 ground estimation, 4.1.4 world lift).

World frame (M3C's convention, also in the README's output section): gravity-aligned, y up, metres; the ground
plane is y = 0 when a ground was found; the origin lies on the ground below the first camera and +z is the first
camera's viewing direction projected onto the ground. Visual odometry gives cameras in its own frame (the first
camera's, translations up to scale); `scale` finds the metric size of one VO unit, `ground` the planes and the
rigid map world_from_vo, `lift` puts every track in the world.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.ground import (CAMERA_UP, ContactTrack, GroundParams, contact_vertices, estimate_ground_planes, fit_plane,
                        level_with_body_up)
from m3c.motion import CONTACT_JOINTS
from m3c.pipeline import ComponentUnavailable, Node, PipelineError, register_node
from m3c.vo.scale import (ScaleEstimate, ScaleObservation, fuse, map_ground_plane, scale_from_camera_height,
                          scale_from_depth, scale_from_planted_feet)


def _poses(track: dict) -> np.ndarray:
    return np.concatenate([track["root_orient"][:, None], track["body_pose"]], axis=1)


def _track_frames(track: dict) -> np.ndarray:
    return track["first_frame"] + np.arange(track["num_frames"])


def contact_joints_in_camera(model, track: dict) -> np.ndarray:
    """(n, 4, 3) positions of the contact joints (ankles, feet) of a camera-frame track."""
    joints = model.joints(_poses(track), track["betas"], track["transl"])
    return joints[:, list(CONTACT_JOINTS)]


def body_up(model, tracks: list[dict], world_from_cam: np.ndarray) -> np.ndarray:
    """Mean unit pelvis-to-neck direction of every visible person-frame in the frame of world_from_cam (camera
    rotations only, so the same at any scale)."""
    directions = []
    for track in tracks:
        frames = np.flatnonzero(track["visible"])
        joints = model.joints(_poses(track)[frames], track["betas"], track["transl"][frames])
        spine = joints[:, 12] - joints[:, 0]
        spine /= np.linalg.norm(spine, axis=1, keepdims=True)
        rotations = world_from_cam[track["first_frame"] + frames, :3, :3]
        directions.append(np.einsum("nij,nj->ni", rotations, spine))
    mean = np.concatenate(directions).mean(axis=0) if directions else np.zeros(3)
    return mean / max(np.linalg.norm(mean), 1e-12)


def estimate_camera_scale(model, tracks: list[dict], cameras: dict, contact_threshold: float = 0.5,
                          depth: dict | None = None, intrinsics=None, log=None) -> ScaleEstimate:
    """The camera scale from every observation that carries it (m3c.vo.scale): the planted feet against the
    camera's motion, the camera's height above the ground (contacts) against the map's ground, and metric
    depth maps when given. cameras: the vo node's output (world_from_cam, points, static)."""
    vo = np.asarray(cameras["world_from_cam"], dtype=np.float64)
    observations = []
    feet = scale_from_planted_feet([contact_joints_in_camera(model, t) for t in tracks],
                                   [(t["contacts"] >= contact_threshold) & t["visible"][:, None]
                                    if "contacts" in t else np.zeros((t["num_frames"], len(CONTACT_JOINTS)), bool)
                                    for t in tracks],
                                   [_track_frames(t) for t in tracks], vo)
    observations.append(feet)
    points = np.asarray(cameras.get("points", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    plane = map_ground_plane(points, vo, body_up(model, tracks, vo)) if tracks else None
    if plane is None:
        observations.append(ScaleObservation("ground", reason="no ground plane among the odometry's "
                                             f"{len(points)} map points"))
    else:
        per_frame = [[] for _ in range(len(vo))]
        for track, points in zip(tracks, contact_vertices(model, tracks, contact_threshold)):
            for i, p in enumerate(points):
                if len(p):
                    per_frame[track["first_frame"] + i].append(p)
        contacts = [np.concatenate(p) if p else np.zeros((0, 3)) for p in per_frame]
        ground = scale_from_camera_height(contacts, vo, plane[:2])
        ground.detail["map_points"] = int(plane[2].sum())
        observations.append(ground)
    if depth is not None and depth.get("available") and depth.get("metric"):
        observations.append(scale_from_depth(points, vo, depth["depth"], intrinsics))
    estimate = fuse(observations)
    if log is not None:
        for o in observations:
            if o.usable():
                log.info("camera scale from %s: %.4g m per VO unit (+-%.1f%%, %d frames)", o.source, o.value,
                         100 * o.sigma, o.frames)
            else:
                log.info("camera scale from %s: not measured (%s)", o.source, o.reason)
        if not estimate.consistent:
            log.warning("the camera scale's sources disagree beyond their uncertainty: %s", ", ".join(
                f"{o.source} {o.value:.4g}" for o in observations if o.usable()))
    return estimate


@register_node
class ScaleNode(Node):
    """The metric size of one visual-odometry translation unit: M3C's one scale estimator (m3c.vo.scale, whose
    docstring states the model), fusing every observation that carries scale with its uncertainty.
    Output scale: value, sigma (standard deviation of log(value); None when nothing measured it), source
    ("given", "static camera", "default", or the sources used, e.g. "planted feet+ground"), consistent,
    observations (per source: value, sigma, frames, reason)."""

    type_name = "scale"
    level = "track"
    inputs = ("tracks", "cameras", "depth", "camera")
    optional_inputs = ("depth", "camera")
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
                                         camera["intrinsics"] if camera is not None else None, ctx.log)
        if estimate.sigma is None:
            ctx.log.warning("nothing measured the camera's scale; starting from 1 m per VO unit")
        else:
            ctx.log.info("camera scale %.4g m per VO unit (+-%.1f%%) from %s", estimate.value,
                         100 * estimate.sigma, estimate.source)
        return {"scale": estimate.to_dict()}


def metric_cameras(world_from_cam: np.ndarray, scale: float) -> np.ndarray:
    out = np.array(world_from_cam, dtype=np.float64, copy=True)
    out[:, :3, 3] *= scale
    return out


def gravity_frame(up: np.ndarray, first_camera: np.ndarray, height: float | None) -> np.ndarray:
    """world_from_vo (4, 4): y along `up`, z along the first camera's view projected off `up`, the origin below
    the first camera at `height` beneath it (or at the camera when height is None)."""
    up = up / np.linalg.norm(up)
    forward = first_camera[:3, 2] - (first_camera[:3, 2] @ up) * up
    if np.linalg.norm(forward) < 1e-6:  # camera looking straight down or up: use its y axis instead
        forward = -first_camera[:3, 1] - (-first_camera[:3, 1] @ up) * up
    forward /= np.linalg.norm(forward)
    R = np.stack([np.cross(up, forward), up, forward])  # rows: world axes in VO coordinates
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = np.array([0.0, height or 0.0, 0.0]) - R @ first_camera[:3, 3]
    return out


@register_node
class GroundNode(Node):
    """The ground and the gravity-aligned world frame (thesis 4.1.3, "Ground Estimation").

    Contact vertices (foot vertices whose contact joint has probability > contact_threshold, in detected frames)
    are placed in the metric VO frame. The dominant ground is a robust plane fit to all of them; it defines the
    world (y up, ground y = 0). Each person's plane per frame is then either that ground (planes: shared, SLAHMR's
    single floor, the default) or the thesis's per-person planes (planes: per_person: m3c.ground's DBSCAN on
    contact points, plane fits, association and filling over time, each frame pooling the contacts of `window`
    frames around it; planes tilted more than max_tilt from the ground are replaced by it).

    Output ground: world_from_vo (4, 4) (metric VO frame at the estimated scale -> world), up_source
    ("ground" or "camera"), plane (normal (3,), offset) the dominant plane in the world (y = 0 when found),
    tracks: per track normal (n, 3), offset (n,) in the world, observed (n,), valid (n,).
    Output scale: the scale node's, passed on (the ground is fitted at that scale).
    """

    type_name = "ground"
    level = "smpl"
    inputs = ("tracks", "cameras", "scale")
    outputs = ("ground", "scale")
    settings = ("body_model",)

    @dataclass
    class Config:
        planes: Literal["shared", "per_person"] = "shared"  # one ground for all (SLAHMR), or the thesis's
        contact_threshold: float = 0.5
        window: int = 15  # frames each side whose contacts join a frame's (0 = per frame, as the thesis)
        max_tilt: float = 10.0  # degrees: a person's plane tilted more from the dominant ground is not kept
        eps: float = 0.15
        min_samples: int = 10
        robust: bool = True
        inlier_threshold: float = 0.02
        min_support: int = 20
        max_iterations: int = 1000
        confidence: float = 0.999
        seed: int = 0
        max_distance: float = 0.10
        fill: Literal["hold", "linear"] = "hold"
        level_with_body_up: bool = True  # tilt the contacts cannot fix comes from the people's upright direction

    def params(self) -> GroundParams:
        c = asdict(self.config)
        for key in ("planes", "contact_threshold", "window", "max_tilt", "level_with_body_up"):
            c.pop(key)
        return GroundParams(**c)

    def run(self, ctx, inputs):
        model = ctx.loaded("body_model")
        tracks = inputs["tracks"]["tracks"]
        vo_cameras = np.asarray(inputs["cameras"]["world_from_cam"], dtype=np.float64)
        scale = dict(inputs["scale"])
        in_camera = contact_vertices(model, tracks, self.config.contact_threshold)
        up = body_up(model, tracks, vo_cameras)  # rotations only: the same at any scale
        cameras = metric_cameras(vo_cameras, scale["value"])
        dominant, pooled, raw = self._dominant(ctx, tracks, in_camera, cameras, up)
        up_vo = cameras[0, :3, :3] @ CAMERA_UP
        per_person = self.config.planes == "per_person" or dominant is None
        contact_tracks = []
        for track, points in zip(tracks, raw if per_person else []):  # (2 x window + 1) copies of every point
            # One foot's sole in one frame hardly fixes a plane (a flexed foot tilts it): each frame also
            # takes the contacts of the frames within `window`, steps at several places on the ground.
            pooled_track = [np.concatenate(points[max(0, t - self.config.window):t + self.config.window + 1])
                            for t in range(len(points))]
            contact_tracks.append(ContactTrack(_track_frames(track), pooled_track,
                                               [np.ones(len(p), bool) for p in pooled_track]))
        if dominant is not None:
            height = float(dominant.signed_distance(cameras[0, :3, 3]))
            world_from_vo = gravity_frame(dominant.normal, cameras[0], height)
            ctx.log.info("ground from %d contact points (rms %.3f m); first camera %.2f m above it", len(pooled),
                         dominant.rms, height)
        else:
            world_from_vo = gravity_frame(up_vo, cameras[0], None)
            ctx.log.warning("no ground found (no planted feet); world up taken from the first camera")
        planes = estimate_ground_planes(contact_tracks, up=up_vo, params=self.params()) \
            if tracks and per_person else []
        R, t = world_from_vo[:3, :3], world_from_vo[:3, 3]
        out_tracks = []
        rejected = 0
        for plane in planes:
            normal = plane.normal @ R.T
            offset = plane.offset - normal @ t
            valid = plane.valid.copy()
            observed = plane.observed.copy()
            if dominant is not None:
                # A plane fitted to a few soles can tilt with the feet; planes parallel to the ground (steps,
                # platforms) are kept, tilted ones give way to the dominant ground, as do frames without one.
                with np.errstate(invalid="ignore"):
                    tilted = valid & (normal[:, 1] < np.cos(np.radians(self.config.max_tilt)))
                rejected += int(tilted.sum())
                replace = ~valid | tilted
                normal[replace] = [0.0, 1.0, 0.0]
                offset[replace] = 0.0
                observed &= ~tilted
                valid[:] = True
            out_tracks.append({"normal": normal, "offset": offset, "observed": observed, "valid": valid})
        if rejected:
            ctx.log.info("%d person-frame plane(s) tilted more than %.0f degrees from the ground were replaced by it",
                         rejected, self.config.max_tilt)
        if not per_person:  # everyone on the dominant ground (y = 0 in the world)
            out_tracks = [{"normal": np.tile([0.0, 1.0, 0.0], (track["num_frames"], 1)),
                           "offset": np.zeros(track["num_frames"]),
                           "observed": np.array([len(p) > 0 for p in points], dtype=bool),
                           "valid": np.ones(track["num_frames"], bool)}
                          for track, points in zip(tracks, raw)]
        return {"ground": {"world_from_vo": world_from_vo, "up_source": "ground" if dominant else "camera",
                           "plane": {"normal": np.array([0.0, 1.0, 0.0]), "offset": 0.0} if dominant else None,
                           "contact_points": int(len(pooled)), "tracks": out_tracks},
                "scale": scale}

    def _dominant(self, ctx, tracks, in_camera, cameras, up_direction):
        """The dominant ground (a PlaneFit in the metric VO frame of `cameras`, or None), all contact points
        there, and per track per frame its contact points there."""
        raw = []
        for track, points in zip(tracks, in_camera):
            world = []
            for i, p in enumerate(points):
                cam = cameras[track["first_frame"] + i]
                world.append(p @ cam[:3, :3].T + cam[:3, 3])
            raw.append(world)
        all_points = [p for points in raw for p in points]
        pooled = np.concatenate(all_points) if all_points else np.zeros((0, 3))
        up_vo = cameras[0, :3, :3] @ CAMERA_UP
        dominant = None
        if len(pooled) >= self.config.min_support:
            try:
                dominant = fit_plane(pooled, up=up_vo, robust=self.config.robust,
                                     inlier_threshold=max(self.config.inlier_threshold, 0.05),
                                     min_support=self.config.min_support, seed=self.config.seed)
            except ValueError as err:
                ctx.log.warning("no ground plane fits the %d contact points: %s", len(pooled), err)
        if dominant is not None and self.config.level_with_body_up:
            dominant, levelled = level_with_body_up(dominant, pooled, up_direction)
            if levelled:
                ctx.log.info("the contact points span a strip or a patch, not an area: the ground's tilt across "
                             "it is taken from the people's upright direction")
        return dominant, pooled, raw


@register_node
class LiftNode(Node):
    """Every track in the world frame (thesis 4.1.4, world lift).

    method camera: each frame's camera-local body moved by its camera (world_from_vo, VO pose at the estimated
    scale). method wham: root orientation and translation from WHAM's trajectory decoder (needs its checkpoint;
    see m3c.models.load_wham), body pose and shape from the local tracks. auto: wham when its checkpoint is found.

    Output world: tracks (per track: track_id, first_frame, num_frames, visible, keypoints, transl, root_orient,
    body_pose, betas, contacts?, ground_normal?, ground_offset?), world_from_cam (T, 4, 4) for the optimizer
    (world rotation, translation in VO units: camera centre = scale * translation), initial_scale, scale_sigma
    (the scale estimator's, None when nothing measured it), scale_source, static, method.
    """

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
        from m3c.models.checkpoint import locate
        from m3c.models.wham import WHAM_SOURCE

        return locate(self.config.checkpoint, ctx.models_dir(), WHAM_SOURCE, self.config.method == "wham")

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
        if path is not None:
            from m3c.models import load_wham

            self._lifter = load_wham(path).to(ctx.device)
            ctx.log.info("WHAM lift with %s on %s", path, ctx.device)

    def unload(self) -> None:
        self._lifter = None

    def run(self, ctx, inputs):
        model = ctx.loaded("body_model")
        video, tracks, ground = inputs["video"], inputs["tracks"]["tracks"], inputs["ground"]
        scale = float(inputs["scale"]["value"])
        world_from_vo = ground["world_from_vo"]
        vo = inputs["cameras"]["world_from_cam"]
        metric = world_from_vo @ metric_cameras(vo, scale)  # world_from_cam, metres at the initial scale
        optimizer_cameras = metric.copy()
        optimizer_cameras[:, :3, 3] /= scale
        lifter = getattr(self, "_lifter", None)
        out = []
        for k, track in enumerate(tracks):
            frames = _track_frames(track)
            j0 = rest_root_joint(model, track["betas"])
            root, transl = transform_smpl(metric[frames], track["root_orient"], track["transl"], j0)
            if lifter is not None:
                from m3c.nodes.wham_lift import wham_trajectory

                root, transl = wham_trajectory(lifter, model, track, metric, root, transl, video,
                                               inputs["camera"]["intrinsics"])
            world = {key: track[key] for key in ("track_id", "first_frame", "num_frames", "visible",
                                                 "keypoints", "body_pose", "betas")}
            world.update(root_orient=root, transl=transl)
            if "contacts" in track:
                world["contacts"] = track["contacts"]
            if ground["tracks"] and ground["tracks"][k]["valid"].all():
                world["ground_normal"] = ground["tracks"][k]["normal"]
                world["ground_offset"] = ground["tracks"][k]["offset"]
            out.append(world)
        return {"world": {"tracks": out, "world_from_cam": optimizer_cameras, "initial_scale": scale,
                          "scale_sigma": inputs["scale"].get("sigma"),
                          "scale_source": str(inputs["scale"].get("source", "")),
                          "static": bool(inputs["cameras"]["static"]),
                          "method": "wham" if lifter is not None else "camera"}}
