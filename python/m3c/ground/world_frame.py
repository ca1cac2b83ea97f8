"""The gravity-aligned world frame from the people's contacts (thesis 4.1.3, "Ground Estimation").

World frame (M3C's convention, also in the README's output section): gravity-aligned, y up, metres; the ground
plane is y = 0 when a ground was found; the origin lies on the ground below the first camera and +z is the first
camera's viewing direction projected onto the ground. Visual odometry gives cameras in its own frame (the first
camera's, translations up to scale); at a camera scale (metres per VO unit) `estimate_ground` finds the planes and
the rigid map world_from_vo.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from m3c.body.transform import spine_directions
from m3c.camera import WorldCameras
from m3c.ground.planes import CAMERA_UP, GroundParams, PlaneFit, RayGroundParams, fit_ground_along_rays
from m3c.ground.tracks import ContactTrack, contact_vertices, estimate_ground_planes, track_frames, track_poses
from m3c.vo.vanishing import agreeing_direction

LOG = logging.getLogger(__name__)


# Person-frames whose spine leans further than this from the people's mean upright direction do not count in it:
# a crouching or bending person (the basketball clip's dribbler leans 43 degrees) is not upright.
MAX_SPINE_LEAN = 25.0


def body_up(model, tracks: list[dict], world_from_cam: np.ndarray) -> np.ndarray:
    """The people's upright direction in the frame of world_from_cam (camera rotations only, so the same at any
    scale): the mean unit pelvis-to-neck direction of the visible person-frames, trimmed (repeatedly) to those
    within MAX_SPINE_LEAN degrees of the mean."""
    directions = []
    for track in tracks:
        frames = np.flatnonzero(track["visible"])
        joints = model.joints(track_poses(track)[frames], track["betas"], track["transl"][frames])
        spine = spine_directions(joints)
        rotations = world_from_cam[track["first_frame"] + frames, :3, :3]
        directions.append(np.einsum("nij,nj->ni", rotations, spine))
    if not directions:
        return np.zeros(3)
    directions = np.concatenate(directions)
    mean = directions.mean(axis=0)
    for _ in range(5):
        mean /= max(np.linalg.norm(mean), 1e-12)
        upright = directions @ mean >= np.cos(np.radians(MAX_SPINE_LEAN))
        if upright.sum() < max(3, len(directions) // 4):  # no clear upright majority: keep the plain mean
            break
        mean = directions[upright].mean(axis=0)
    return mean / max(np.linalg.norm(mean), 1e-12)


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


# The odometry map's ground is the people's when their contacts lie this close to it (median, metres): the scale's
# ground source made their mean heights agree, so a larger gap means the map's plane is another surface.
MAX_MAP_GROUND_GAP = 0.3


def tilt_prior(up_direction: np.ndarray, level: bool, first_camera: np.ndarray,
               scene_up: tuple[np.ndarray, float, float] | None, ray_params: RayGroundParams = RayGroundParams()
               ) -> tuple[str, np.ndarray, RayGroundParams]:
    """(name, up direction, the fit's noise model) of the contacts' ground's tilt prior: the scene's vertical edges
    ("scene", at its sigmas sideways and forwards) when scene_up is given, else the people's upright direction ("people") when
    `level` and known, else the first camera's up ("camera")."""
    if scene_up is not None:
        return "scene", scene_up[0], replace(ray_params, roll_sigma=scene_up[1], pitch_sigma=scene_up[2])
    if level and np.linalg.norm(up_direction) > 0:
        return "people", up_direction, ray_params
    return "camera", first_camera[:3, :3] @ CAMERA_UP, ray_params


def dominant_ground(in_camera: list[list[np.ndarray]], tracks: list[dict], cameras: np.ndarray,
                    up_direction: np.ndarray, params: GroundParams, level: bool = True, log=LOG,
                    map_plane: np.ndarray | None = None, ray_params: RayGroundParams = RayGroundParams(),
                    scene_up: tuple[np.ndarray, float, float] | None = None
                    ) -> tuple[PlaneFit | None, str | None, np.ndarray, list[list[np.ndarray]]]:
    """The dominant ground (a PlaneFit in the metric VO frame of `cameras`, or None), where it came from
    ("odometry map", "contacts" or None), all contact points there, and per track per frame its contact points
    there. in_camera: contact_vertices' output; up_direction: the people's upright direction (body_up), the
    prior of the contacts' ground's tilt when `level` (else the first camera's up).
    map_plane: the odometry map's ground in the metric VO frame (normal (3,), offset), taken when the contacts
    lie on it (MAX_MAP_GROUND_GAP): thousands of static points spread over the scene fix its tilt better than
    feet whose monocular depth swings by metres within a second; otherwise the contacts' ground
    (m3c.ground.planes.fit_ground_along_rays: one point per person and frame, its error along the camera ray).
    scene_up: (up direction in the VO frame, its sigmas sideways and forwards in degrees) from the scene's vertical
    edges (scene_up_prior): the contacts' ground's tilt prior instead of the people's upright direction."""
    raw, frame_points, frame_centers = [], [], []
    for track, points in zip(tracks, in_camera):
        world = []
        for i, p in enumerate(points):
            cam = cameras[track["first_frame"] + i]
            world.append(p @ cam[:3, :3].T + cam[:3, 3])
            if len(p):
                frame_points.append(world[-1].mean(axis=0))
                frame_centers.append(cam[:3, 3])
        raw.append(world)
    all_points = [p for points in raw for p in points]
    pooled = np.concatenate(all_points) if all_points else np.zeros((0, 3))
    dominant = None
    if map_plane is not None and len(pooled) >= params.min_support:
        normal, offset = np.asarray(map_plane[0], dtype=np.float64), float(map_plane[1])
        heights = pooled @ normal + offset
        gap = float(np.median(heights))
        if abs(gap) <= MAX_MAP_GROUND_GAP:
            inliers = np.abs(heights - gap) < max(params.inlier_threshold, 0.05)
            dominant = PlaneFit(normal, offset, inliers, float(np.sqrt(np.mean(heights[inliers] ** 2))))
            log.info("ground: the odometry map's ground plane (the people's contacts %.2f m above it, median)", gap)
            return dominant, "odometry map", pooled, raw
        log.info("the odometry map's ground plane lies %.2f m from the people's contacts (median): the ground "
                 "from the contacts", gap)
    if len(pooled) >= params.min_support:
        _, prior, ray_params = tilt_prior(up_direction, level, cameras[0], scene_up, ray_params)
        try:
            dominant = fit_ground_along_rays(np.array(frame_points), np.array(frame_centers), prior,
                                             cameras[0, :3, 0], ray_params)
        except ValueError as err:
            log.warning("no ground plane fits the %d contact points: %s", len(pooled), err)
    return dominant, "contacts" if dominant is not None else None, pooled, raw


# The scene's up direction counts when its frames agree within MAX_UP_SPREAD (RMS degrees, in the VO frame), and is
# trusted to no better than this.
MIN_SCENE_UP_SIGMA = 2.0


def scene_up_prior(scene: dict | None, vo_cameras: np.ndarray, focal_log_sigma: float = 0.0, log=LOG
                   ) -> tuple[np.ndarray, float, float] | None:
    """(up direction in the VO frame, its sigma sideways and forwards in degrees) from the focal node's scene
    record (m3c.vo.vanishing: each sampled frame's up direction in its camera, at the focal length the run goes
    on with), or None: without a record, or where the frames' up directions, rotated into the VO frame, do not
    agree within MAX_UP_SPREAD degrees (m3c.vo.vanishing.agreeing_direction: not one family of vertical edges).

    A vertical vanishing point gives the up direction's forward tilt only through the focal length (the up ray
    is (a, b, f w)): an error of d log f tilts it by sin(t) cos(t) d log f radians in a camera looking t off
    level, so the forward sigma adds focal_log_sigma (the camera record's: 0 for given intrinsics, about 0.3 for
    the default) at the frames' median tilt. The focal length need not come from the scene's own lines: on the
    video benchmark the scene's up lay within 0.2-2.3 degrees of the truth (median over sampled frames) on every
    sequence, with the focal length from the motion, the people or the default."""
    if not scene:
        return None
    frames = [f for f in scene.get("frames", []) if f.get("up") is not None and 0 <= f["frame"] < len(vo_cameras)]
    in_camera = np.array([f["up"] for f in frames], dtype=np.float64).reshape(-1, 3)
    ups = np.array([np.asarray(vo_cameras[f["frame"], :3, :3], dtype=np.float64) @ up
                    for f, up in zip(frames, in_camera)]).reshape(-1, 3)
    if len(ups) < 2:
        return None
    mean, spread, kept = agreeing_direction(ups)
    if mean is None:
        log.info("the scene's vertical edges give up directions %.1f degrees apart (RMS over %d of %d frames): "
                 "not used", spread, int(kept.sum()), len(ups))
        return None
    sideways = max(spread, MIN_SCENE_UP_SIGMA)
    tilt = np.abs(in_camera[kept, 2])  # sin of each frame's tilt off level
    forward = math.hypot(sideways, math.degrees(float(np.median(tilt * np.sqrt(1.0 - tilt ** 2))) * focal_log_sigma))
    return mean, sideways, forward


def estimate_ground(model, tracks: Sequence[dict], vo_cameras: np.ndarray, scale: float, params: GroundParams, *,
                    planes: str = "shared", contact_threshold: float = 0.5, window: int = 15,
                    max_tilt: float = 10.0, level: bool = True, log=LOG, map_plane=None,
                    scene: dict | None = None, focal_log_sigma: float = 0.0) -> dict:
    """The ground and the gravity-aligned world frame of camera-frame tracks seen by VO cameras at `scale`.

    Contact vertices (foot vertices whose contact joint has probability > contact_threshold, in detected frames)
    are placed in the metric VO frame. The dominant ground is the odometry map's ground plane when one is given
    (map_plane: (nx, ny, nz, d) in the VO frame and VO units, the scale estimate's ground_plane) and the contacts
    lie on it, else a robust plane fit to the contacts, its tilt held by the scene's vertical edges where the
    focal node measured them (scene: its camera's scene record, focal_log_sigma: its focal length's uncertainty;
    scene_up_prior), else by the people's upright direction; it defines the world (y up, ground y = 0). Each person's
    plane per frame is then either that ground (planes "shared", SLAHMR's single floor) or the thesis's
    per-person planes (planes "per_person": DBSCAN on contact points, plane fits, association and filling over
    time, each frame pooling the contacts of `window` frames around it; planes tilted more than max_tilt degrees
    from the ground are replaced by it).

    Returns {world_from_vo (4, 4) (metric VO frame -> world), cameras (m3c.camera.WorldCameras: the cameras in
    the world at `scale`), up_source ("ground" or "camera"), ground_source ("odometry map", "contacts" or None),
    tilt_prior (what held the contacts' ground's tilt: "scene", "people", "camera"; None for another source),
    plane (normal (3,), offset) the dominant plane in the world (y = 0) or None, contact_points, tracks: per track
    normal (n, 3), offset (n,) in the world, observed (n,), valid (n,)}.
    """
    tracks = list(tracks)
    in_camera = contact_vertices(model, tracks, contact_threshold)
    up = body_up(model, tracks, vo_cameras)  # rotations only: the same at any scale
    cameras = WorldCameras.from_vo(vo_cameras, scale).world_from_cam()  # the VO frame in metres
    if map_plane is not None:  # (nx, ny, nz, d) in VO units (the scale estimate's ground_plane) -> metres
        plane = np.asarray(map_plane, dtype=np.float64)
        norm = np.linalg.norm(plane[:3]) if plane.shape == (4,) else 0.0
        if not (np.isfinite(plane).all() and norm > 0):
            raise ValueError(f"map_plane must be 4 finite numbers (nx, ny, nz, d) with a non-zero normal, "
                             f"got {plane}")
        map_plane = (plane[:3] / norm, scale * plane[3] / norm)
    scene_up = scene_up_prior(scene, vo_cameras, focal_log_sigma, log)
    if scene_up is not None:
        log.info("ground tilt prior: the scene's vertical edges (+-%.1f degrees sideways, %.1f forwards)", *scene_up[1:])
    dominant, ground_source, pooled, raw = dominant_ground(in_camera, tracks, cameras, up, params, level, log,
                                                           map_plane, scene_up=scene_up)
    up_vo = cameras[0, :3, :3] @ CAMERA_UP
    per_person = planes == "per_person" or dominant is None
    contact_tracks = []
    for track, points in zip(tracks, raw if per_person else []):  # (2 x window + 1) copies of every point
        # One foot's sole in one frame hardly fixes a plane (a flexed foot tilts it): each frame also
        # takes the contacts of the frames within `window`, steps at several places on the ground.
        pooled_track = [np.concatenate(points[max(0, t - window):t + window + 1]) for t in range(len(points))]
        contact_tracks.append(ContactTrack(track_frames(track), pooled_track,
                                           [np.ones(len(p), bool) for p in pooled_track]))
    if dominant is not None:
        height = float(dominant.signed_distance(cameras[0, :3, 3]))
        world_from_vo = gravity_frame(dominant.normal, cameras[0], height)
        log.info("ground from %d contact points (rms %.3f m); first camera %.2f m above it", len(pooled),
                 dominant.rms, height)
    else:
        world_from_vo = gravity_frame(up_vo, cameras[0], None)
        log.warning("no ground found (no planted feet); world up taken from the first camera")
    person_planes = estimate_ground_planes(contact_tracks, up=up_vo, params=params) if tracks and per_person else []
    R, t = world_from_vo[:3, :3], world_from_vo[:3, 3]
    out_tracks = []
    rejected = 0
    for plane in person_planes:
        normal = plane.normal @ R.T
        offset = plane.offset - normal @ t
        valid = plane.valid.copy()
        observed = plane.observed.copy()
        if dominant is not None:
            # A plane fitted to a few soles can tilt with the feet; planes parallel to the ground (steps,
            # platforms) are kept, tilted ones give way to the dominant ground, as do frames without one.
            with np.errstate(invalid="ignore"):
                tilted = valid & (normal[:, 1] < np.cos(np.radians(max_tilt)))
            rejected += int(tilted.sum())
            replace = ~valid | tilted
            normal[replace] = [0.0, 1.0, 0.0]
            offset[replace] = 0.0
            observed &= ~tilted
            valid[:] = True
        out_tracks.append({"normal": normal, "offset": offset, "observed": observed, "valid": valid})
    if rejected:
        log.info("%d person-frame plane(s) tilted more than %.0f degrees from the ground were replaced by it",
                 rejected, max_tilt)
    if not per_person:  # everyone on the dominant ground (y = 0 in the world)
        out_tracks = [{"normal": np.tile([0.0, 1.0, 0.0], (track["num_frames"], 1)),
                       "offset": np.zeros(track["num_frames"]),
                       "observed": np.array([len(p) > 0 for p in points], dtype=bool),
                       "valid": np.ones(track["num_frames"], bool)}
                      for track, points in zip(tracks, raw)]
    return {"world_from_vo": world_from_vo, "cameras": WorldCameras.from_vo(vo_cameras, scale, world_from_vo),
            "up_source": "ground" if dominant else "camera", "ground_source": ground_source,
            "tilt_prior": tilt_prior(up, level, cameras[0], scene_up)[0] if ground_source == "contacts" else None,
            "plane": {"normal": np.array([0.0, 1.0, 0.0]), "offset": 0.0} if dominant else None,
            "contact_points": int(len(pooled)), "tracks": out_tracks}
