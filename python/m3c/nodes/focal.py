"""The focal length of a camera nobody calibrated, found from the camera's own motion (m3c.vo.focal) or, where
the motion cannot tell, from the scene's vanishing points (m3c.vo.vanishing), or for a still camera from the
people's planted feet against the scene's vertical vanishing point (m3c.vo.ground_focal)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from m3c.nodes.frames import stream_frames
from m3c.nodes.records import people_mask, rows_by_frame
from m3c.pipeline import InputError, Node, PipelineError, register_node


@register_node
class FocalNode(Node):
    """Estimates the focal length when the camera node has only its default (no --intrinsics), by the search of
    m3c.vo.focal: the patch odometry's first bundle adjustment over windows of frames (people's masks hidden
    from it, as in the vo node) at candidate focal lengths; the least cost wins. A camera that only translates or
    stands still leaves the cost flat: then the scene's lines decide where they can (m3c.vo.vanishing: vertical
    edges and perpendicular horizontal ones, agreeing over frames sampled through the video), else, for a camera
    that stands still, the people where they can (m3c.vo.ground_focal: their planted feet over time locate the
    horizon, which with the vertical vanishing point gives the focal length), else the default is kept; the log
    says which. The scene's up direction per sampled frame is measured either way (given intrinsics included) for
    the ground node.

    It runs after perception because the odometry needs the people's masks, and perception fitted the bodies at
    the camera node's focal: a body's camera-local depth scales with the focal (its root keeps its pixel when x, y
    stay and z is multiplied by f_new / f_old), so the tracks output is perception's tracks with each transl
    re-expressed at the estimated focal (a weak-perspective crop_cam needs nothing: local_tracks converts it with
    this camera).

    Output camera: intrinsics (4,), source ("given", "default", "estimated" (the motion), "scene" or "people"),
    focal_estimate (the search's summary, m3c.vo.focal.FocalEstimate.summary(); None when no search ran), scene
    (m3c.vo.vanishing.SceneCamera.summary() at the final focal length: per sampled frame its focal length and up
    direction; None when scene_lines is off), feet_focal (m3c.vo.ground_focal.GroundFocal.summary(); None when it
    did not run). Output tracks: perception's tracks ({"tracks": [...]}, m3c.perception.handover), re-expressed.
    Config: enabled (false: pass the camera node's intrinsics through), motion (false: no odometry search, for a
    camera known to stand still), search: m3c.vo.focal.FocalSearchConfig settings, scene_lines (false: no scene
    estimate), scene: m3c.vo.vanishing.SceneLineConfig settings, planted_feet (false: no estimate from the
    people), feet: m3c.vo.ground_focal.GroundFocalConfig settings."""

    type_name = "focal"
    level = "patch"
    inputs = ("video", "camera", "masks", "detections", "tracks")
    optional_inputs = ("masks", "detections", "tracks")
    outputs = ("camera", "tracks")
    # 2: re-expresses perception's tracks (it re-expressed the per-detection body table)
    # 3: the search goes on past an end of its range where the least cost lies near it (max_extension)
    # 4: the scene's vanishing points (focal length where the motion cannot tell, up direction); 5: the people's
    # planted feet (a still camera's focal length where the scene's lines cannot tell); 6: a sampled frame whose
    # vertical vanishing point is another family of edges is left out of a still camera's vertical; 7: a frame's
    # scene focal length counts only where its own segments hold it (jackknife), camera.scene.log_sigma; 8: the
    # people's focal length counts within log-sigma 0.2 (was 0.15)
    version = "8"
    settings = ("body_model",)

    @dataclass
    class Config:
        enabled: bool = True
        motion: bool = True  # the odometry's search (false for a camera known to stand still: --static-camera)
        search: dict[str, Any] = field(default_factory=dict)
        scene_lines: bool = True  # the scene's vanishing points where the motion cannot tell (m3c.vo.vanishing)
        scene: dict[str, Any] = field(default_factory=dict)
        planted_feet: bool = True  # a still camera's people against the scene's vertical (m3c.vo.ground_focal)
        feet: dict[str, Any] = field(default_factory=dict)

    def _settings(self, key: str):
        """The settings dataclass of focal.<key> ("search", "scene" or "feet"), or an InputError naming the bad
        one."""
        from m3c.vo.focal import FocalSearchConfig
        from m3c.vo.ground_focal import GroundFocalConfig
        from m3c.vo.vanishing import SceneLineConfig

        cls = {"search": FocalSearchConfig, "scene": SceneLineConfig, "feet": GroundFocalConfig}[key]
        try:
            return cls(**getattr(self.config, key))
        except (TypeError, ValueError) as err:
            raise InputError(f"node {self.name!r}: bad setting in focal.{key} ({err}); settings are "
                             f"{cls.__module__}.{cls.__name__} fields") from None

    def check(self, ctx) -> None:
        self._settings("search")
        self._settings("scene")
        self._settings("feet")

    def run(self, ctx, inputs):
        import cv2

        from m3c.vo.focal import estimate_focal_windows, focal_windows, reduce_frame
        from m3c.vo.vanishing import estimate_scene_camera

        camera, tracks = dict(inputs["camera"]), inputs["tracks"]
        camera["focal_estimate"] = None
        camera["scene"] = None
        camera["feet_focal"] = None
        if not self.config.enabled:
            return {"camera": camera, "tracks": tracks}
        video, masks, detections = inputs["video"], inputs["masks"], inputs["detections"]
        if (masks is None) != (detections is None):
            raise PipelineError(f"node {self.name!r}: wire both masks and detections (to hide people from the "
                                "odometry) or neither")
        config = self._settings("search")
        scene_config = self._settings("scene") if self.config.scene_lines else None
        search = camera.get("source") == "default" and self.config.motion
        if not search and scene_config is None:
            return {"camera": camera, "tracks": tracks}
        T, width, height = int(video["num_frames"]), int(video["width"]), int(video["height"])
        windows = focal_windows(T, config) if search else []
        wanted = {i: k for k, (a, b) in enumerate(windows) for i in range(a, b)}
        scene_frames = sorted(set(np.linspace(0, T - 1, scene_config.frames).round().astype(int).tolist())) \
            if scene_config else []
        rows = rows_by_frame(detections) if masks is not None else {}
        clips: list[tuple[list, list]] = [([], []) for _ in windows]
        scene_gray, scene_masks = [], []
        last = max(list(wanted) + scene_frames, default=-1)
        with ctx.progress("frames", len(set(wanted) | set(scene_frames))) as bar:
            for i, frame in stream_frames(ctx, video):
                if i in wanted or i in scene_frames:
                    mask = None if masks is None else people_mask(masks, rows.get(i, []), width, height)
                    if i in wanted:
                        gray, small = reduce_frame(frame, mask, config.max_image_side)
                        clips[wanted[i]][0].append(gray)
                        clips[wanted[i]][1].append(small)
                    if i in scene_frames:
                        scene_gray.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
                        scene_masks.append(mask)
                    bar.update()
                if i >= last:
                    break
        focal, estimate = None, None
        if search:
            clips = [(np.stack(f), None if masks is None else np.stack(m)) for f, m in clips]
            estimate = estimate_focal_windows(clips, width, height, config, log=ctx.log.debug)
            estimate.windows = windows
            ctx.log.info("focal search over frames %s: %s", ", ".join(f"{a}..{b - 1}" for a, b in windows),
                         estimate.message)
            camera["focal_estimate"] = estimate.summary()
            if estimate.informative:
                focal, source = estimate.focal, "estimated"
        scene = None
        if scene_config is not None:
            scene = estimate_scene_camera(scene_gray, scene_masks if masks is not None else None, scene_config,
                                          scene_frames)
            ctx.log.info("focal length from the scene's lines: %s", scene.reason)
            if camera.get("source") == "default" and focal is None and scene.informative:
                focal, source = scene.focal, "scene"
        old = np.asarray(camera["intrinsics"], dtype=np.float64)
        old_focal = float(np.mean(old[:2]))
        still = not self.config.motion or (estimate is not None and estimate.still)
        if (camera.get("source") == "default" and focal is None and still and scene is not None
                and self.config.planted_feet and tracks is not None):
            feet = self._feet_focal(ctx, scene, tracks["tracks"], old_focal)
            camera["feet_focal"] = feet.summary()
            if feet.informative:
                focal, source = feet.focal, "people"
        if focal is not None:
            camera["intrinsics"] = np.array([focal, focal, old[2], old[3]])
            camera["source"] = source
            if tracks is not None:
                factor = focal / old_focal
                tracks = dict(tracks, tracks=[refocused(track, factor) for track in tracks["tracks"]])
        if scene is not None:  # each frame's up direction at the focal length the run goes on with
            camera["scene"] = scene.summary(focal if focal is not None else old_focal)
        return {"camera": camera, "tracks": tracks}

    def _feet_focal(self, ctx, scene, tracks: list[dict], default: float):
        """m3c.vo.ground_focal's estimate from the tracks' planted feet and the scene's vertical vanishing point."""
        from m3c.vo.ground_focal import GroundFocal, focal_from_planted_feet, planted_points, scene_vertical

        config = self._settings("feet")
        vertical, why = scene_vertical(scene, default)
        if vertical is None:
            feet = GroundFocal(default, default, message=f"no vertical vanishing point: {why}")
        else:
            people = planted_points(ctx.loaded("body_model"), tracks, default, config.contact_threshold)
            feet = focal_from_planted_feet(people, vertical, default, config)
        ctx.log.info("focal length from the people's planted feet: %s", feet.message)
        return feet


def refocused(track: dict, factor: float) -> dict:
    """A perception track seen by a camera whose focal length is `factor` times the one it was fitted at: its
    depths times factor, which keeps every root's pixel (a crop_cam track needs no change)."""
    if "transl" not in track:
        return track
    transl = np.array(track["transl"], dtype=np.float64)
    transl[:, 2] *= factor
    return dict(track, transl=transl)
