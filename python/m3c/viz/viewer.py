"""`m3c view OUT_DIR`: the results in the browser, on viser (a WebGL scene with a GUI, served from Python).

The 3D view shows the ground (y = 0 when the run found one), every person's mesh (optimized motion, and the
world lift before optimization), the video
camera's frustum with the current frame on it, and the camera's path; its camera is free or follows the people
as the world view's chase camera does ("View" > camera: follow). The panel beside it has the timeline
(slider, play/pause, frame steps), the video frame (overlay.mp4 of the folder, or the source video when
given), toggles for each layer, and per-track figures from results.json.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.export.source import ExportSource, load_source
from m3c.viz.scene import track_colour

MAX_IMAGE_WIDTH = 480    # video frames shown in the panel and on the frustum are downscaled to this width
# results.json per-track fields shown in the panel (any other numeric field, e.g. plausibility figures, follows).
_TRACK_FIELDS = {"frames": "frames", "visible_frames": "detected", "mean_reprojection_error_px": "reproj. px",
                 "path_length_m": "path m", "height_m": "height m"}


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return np.array([w, x, y, z])


class ChunkedVertices:
    """A track's world vertices (n, V, 3) computed a chunk of frames at a time when first asked for, so that long
    videos with many people do not hold every frame's mesh in memory."""

    def __init__(self, model, pose: np.ndarray, betas: np.ndarray, transl: np.ndarray, chunk: int = 32):
        self.model, self.pose, self.betas, self.transl, self.chunk = model, pose, betas, transl, chunk
        self._start, self._verts = -1, None

    def __len__(self) -> int:
        return len(self.pose)

    def __getitem__(self, k: int) -> np.ndarray:
        if self._verts is None or not self._start <= k < self._start + len(self._verts):
            self._start = k - k % self.chunk
            stop = min(self._start + self.chunk, len(self.pose))
            self._verts = self.model.forward(self.pose[self._start:stop], self.betas,
                                             self.transl[self._start:stop]).vertices
        return self._verts[k - self._start]


def track_vertices(source: ExportSource, lift: bool) -> list[ChunkedVertices]:
    """Per track its world vertices over its frames: the optimized motion, or the world lift (its root
    orientation and translation; its body pose and shape when the results hold them, lift_body_pose and
    lift_betas, else the optimized ones)."""
    arrays = source.arrays
    out = []
    for track in source.tracks:
        pose, transl, betas = track.pose.copy(), track.transl, track.betas
        if lift:
            p, f = track.index, track.frames
            pose[:, 0] = arrays["lift_world_root_orient"][p, f]
            if "lift_body_pose" in arrays:
                pose[:, 1:] = arrays["lift_body_pose"][p, f]
            if "lift_betas" in arrays:
                betas = arrays["lift_betas"][p].astype(np.float64)
            transl = arrays["lift_world_transl"][p, f].astype(np.float64)
        out.append(ChunkedVertices(source.model, pose.astype(np.float32), betas.astype(np.float32),
                                   transl.astype(np.float32)))
    return out


class EncodedFrames:
    """Video frames kept JPEG-encoded (about 20 kB each instead of 400 kB), decoded to RGB when shown."""

    def __init__(self, frames_bgr: list[np.ndarray]):
        import cv2

        self._jpegs = [cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 90])[1] for f in frames_bgr]

    def __len__(self) -> int:
        return len(self._jpegs)

    def __getitem__(self, k: int) -> np.ndarray:
        import cv2

        return cv2.imdecode(self._jpegs[k], cv2.IMREAD_COLOR)[..., ::-1].copy()


def load_frames(folder: Path, source: ExportSource, video: str | Path | None = None) -> EncodedFrames | None:
    """Frames for each processed frame: the source video's frames by frame_ids when `video` is given, else
    the folder's overlay.mp4 (one frame per processed frame); None when neither exists."""
    import cv2

    from m3c.io.video import iter_frames

    path = Path(video) if video is not None else folder / "overlay.mp4"
    if not path.is_file():
        if video is not None:
            raise FileNotFoundError(f"video not found: {path}")
        return None
    frame_ids = source.arrays["frame_ids"]
    wanted = set(int(f) for f in frame_ids) if video is not None else None
    frames = {}
    for index, frame in iter_frames(path):
        key = index if wanted is None else (index if index in wanted else None)
        if key is None:
            continue
        h, w = frame.shape[:2]
        if w > MAX_IMAGE_WIDTH:
            frame = cv2.resize(frame, (MAX_IMAGE_WIDTH, round(h * MAX_IMAGE_WIDTH / w)), interpolation=cv2.INTER_AREA)
        frames[key] = frame
        if len(frames) == len(frame_ids):
            break
    keys = list(range(len(frame_ids))) if wanted is None else [int(f) for f in frame_ids]
    if not all(k in frames for k in keys):
        return None
    return EncodedFrames([frames[k] for k in keys])


def track_table(summary: dict, track_ids) -> str:
    """Markdown table of results.json's per-track figures for the shown tracks."""
    rows = [t for t in summary.get("tracks", []) if t.get("id") in set(int(i) for i in track_ids)]
    if not rows:
        return "No per-track figures in results.json."
    extra = sorted({k for t in rows for k, v in t.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
                    and k not in _TRACK_FIELDS and k not in ("id", "first_frame", "last_frame")})
    nested = sorted({f"{k}.{kk}" for t in rows for k, v in t.items() if isinstance(v, dict)
                     for kk, vv in v.items() if isinstance(vv, (int, float)) and not isinstance(vv, bool)})
    header = ["track", *_TRACK_FIELDS.values(), *extra, *nested]

    def value(t, key):
        if "." in key:
            outer, inner = key.split(".", 1)
            v = t.get(outer, {}).get(inner)
        else:
            v = t.get(key)
        return "n/a" if v is None else (f"{v:.3g}" if isinstance(v, float) else str(v))

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for t in rows:
        lines.append("| " + " | ".join([str(t["id"])] + [value(t, k) for k in [*_TRACK_FIELDS, *extra, *nested]])
                     + " |")
    return "\n".join(lines)


class ResultViewer:
    """The scene and GUI of one result folder on a viser server."""

    def __init__(self, server, folder: str | Path, body_model: str | Path | None = None,
                 video: str | Path | None = None):
        self.server, self.folder = server, Path(folder)
        self.source = source = load_source(self.folder, None, body_model)
        self.num_frames = source.num_frames
        self.frame = 0
        self.images = load_frames(self.folder, source, video)
        self.vertices = {"optimized": track_vertices(source, lift=False), "lift": track_vertices(source, lift=True)}
        self._lock = threading.RLock()  # set_frame moves the slider, whose callback calls set_frame
        scene, gui = server.scene, server.gui
        scene.set_up_direction("+y")
        self._add_ground()
        self._initial_view()
        world_from_cam = source.arrays["world_from_cam"].astype(np.float64)
        centres = world_from_cam[:, :3, 3]
        if len(centres) > 1:
            scene.add_line_segments("/camera/path", np.stack([centres[:-1], centres[1:]], axis=1),
                                    colors=(40, 40, 40), thickness=0.01)
        width, height = source.image_size
        self.frustum = scene.add_camera_frustum("/camera/frustum", fov=source.vertical_fov, aspect=width / height, scale=0.4, color=(30, 30, 30))
        faces = np.asarray(source.model.faces, dtype=np.uint32)
        self.meshes = {layer: [] for layer in self.vertices}
        for layer, per_track in self.vertices.items():
            for track, verts in zip(source.tracks, per_track):
                colour = track_colour(track.track_id)
                if layer == "lift":
                    colour = 0.55 * colour + 0.45
                self.meshes[layer].append(scene.add_mesh_simple(
                    f"/{layer}/track{track.track_id}", verts[0], faces, color=tuple(int(255 * c) for c in colour),
                    opacity=None if layer == "optimized" else 0.5, visible=layer == "optimized"))

        with gui.add_folder("Timeline"):
            self.slider = gui.add_slider("frame", min=0, max=max(self.num_frames - 1, 1), step=1, initial_value=0,
                                         disabled=self.num_frames < 2)
            self.playing = gui.add_checkbox("play", initial_value=False)
            self.speed = gui.add_slider("speed", min=0.25, max=2.0, step=0.25, initial_value=1.0)
            steps = gui.add_button_group("step", ("-10", "-1", "+1", "+10"))
            self.label = gui.add_markdown("")
        steps.on_click(lambda event: self.set_frame(self.frame + int(event.target.value)))
        self.slider.on_update(lambda _: int(self.slider.value) != self.frame and self.set_frame(int(self.slider.value)))
        self.image = gui.add_image(self.images[0], label="video") if self.images else None
        self.chase = self._chase_view()
        with gui.add_folder("View"):
            # "follow": the camera of the world view (m3c.viz.chase), framed on the people, smoothed over time.
            self.camera_mode = gui.add_dropdown("camera", ("free", "follow"), initial_value="free")
        self.camera_mode.on_update(lambda _: self.set_frame(self.frame))
        with gui.add_folder("Show"):
            self.show = {"optimized": gui.add_checkbox("optimized motion", initial_value=True),
                         "lift": gui.add_checkbox("world lift (before optimization)", initial_value=False),
                         "camera": gui.add_checkbox("camera", initial_value=True)}
        for box in self.show.values():
            box.on_update(lambda _: self.set_frame(self.frame))
        with gui.add_folder("Tracks"):
            gui.add_markdown(track_table(source.summary, [t.track_id for t in source.tracks]))
        self.set_frame(0)

    def _chase_view(self):
        from m3c.viz.chase import ChaseView

        source = self.source
        people = [[] for _ in range(self.num_frames)]
        for track in source.tracks:
            pelvis = track.world_joints[:, [1, 2]].mean(axis=1)
            for frame, point in zip(track.frames, pelvis):
                people[int(frame)].append(point)
        lowest = min(float(np.min(t.world_joints[..., 1])) for t in source.tracks) if source.tracks else 0.0
        return ChaseView([np.array(p, dtype=np.float64).reshape(-1, 3) for p in people],
                         source.arrays["world_from_cam"][:, :3, 3].astype(np.float64),
                         0.0 if source.ground_found else lowest, float(source.fps))

    def follow(self, frame: int) -> None:
        """Puts every connected browser's camera where the world view's chase camera is at `frame`."""
        pose = self.chase.poses[frame]
        for client in self.server.get_clients().values():
            with client.atomic():
                client.camera.position = pose[:3, 3]
                client.camera.look_at = self.chase.targets[frame]

    def _add_ground(self) -> None:
        source = self.source
        lo, hi = source.ground_extent()
        centre, size = (lo + hi) / 2, hi - lo
        lowest = min(float(np.min(t.world_joints[..., 1])) for t in source.tracks)
        height = 0.0 if source.ground_found else lowest
        # The grid's plane "xz" is spanned by world x and z; it sits at y = ground height.
        self.server.scene.add_grid("/ground", width=float(size[0]), height=float(size[1]), plane="xz",
                                   cell_size=0.5, section_size=1.0, position=(float(centre[0]), height,
                                                                              float(centre[1])))

    def _initial_view(self, frame: int = 0) -> None:
        """Look from the side and above at the middle between the people and the video camera at `frame`."""
        source = self.source
        people = [t.world_joints[np.searchsorted(t.frames, frame).clip(0, len(t.frames) - 1), 0]
                  for t in source.tracks]
        camera = source.arrays["world_from_cam"][frame, :3, 3].astype(np.float64)
        target = 0.5 * (np.mean(people, axis=0) + camera)
        target[1] = 0.5 * camera[1]
        back = camera - np.mean(people, axis=0)
        back[1] = 0.0
        back = back / max(np.linalg.norm(back), 1e-6)
        side = np.cross([0.0, 1.0, 0.0], back)
        self.server.initial_camera.look_at = target
        self.server.initial_camera.position = target + 7.0 * side + 2.0 * back + np.array([0.0, 3.5, 0.0])

    def set_frame(self, frame: int) -> None:
        """Shows processed frame `frame` (clamped to the video)."""
        with self._lock:
            frame = int(np.clip(frame, 0, self.num_frames - 1))
            self.frame = frame
            if int(self.slider.value) != frame:
                self.slider.value = frame
            for layer, handles in self.meshes.items():
                for track, verts, handle in zip(self.source.tracks, self.vertices[layer], handles):
                    k = np.searchsorted(track.frames, frame)
                    inside = k < len(track.frames) and track.frames[k] == frame
                    if inside and self.show[layer].value:
                        handle.vertices = verts[k]
                    handle.visible = bool(inside and self.show[layer].value)
            pose = self.source.arrays["world_from_cam"][frame].astype(np.float64)
            self.frustum.position = pose[:3, 3]
            self.frustum.wxyz = _wxyz(pose[:3, :3])   # viser frusta look down +z with y down, as OpenCV's
            self.frustum.visible = bool(self.show["camera"].value)
            if self.images:
                image = self.images[frame]
                self.frustum.image = image
                self.image.image = image
            if self.camera_mode.value == "follow":
                self.follow(frame)
            video_frame = int(self.source.arrays["frame_ids"][frame])
            self.label.content = (f"processed frame {frame} of {self.num_frames} (video frame {video_frame}, "
                                  f"t = {frame / self.source.fps:.2f} s)")

    def step(self) -> None:
        """Advances one frame when playing (wrapping at the end)."""
        if self.playing.value and self.num_frames > 1:
            self.set_frame((self.frame + 1) % self.num_frames)


def serve(folder: str | Path, host: str = "127.0.0.1", port: int = 8080, body_model: str | Path | None = None,
          video: str | Path | None = None, stop: threading.Event | None = None, ready=None) -> None:
    """Serves the viewer until interrupted (or `stop` is set); `ready(viewer)` is called once it is up."""
    try:
        import viser
    except ImportError:
        raise ImportError("`m3c view` needs viser: pip install 'm3c[viewer]' (or pip install viser)") from None
    load_source(folder, None, body_model)  # a bad folder fails before the server starts
    server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        viewer = ResultViewer(server, folder, body_model, video)
        print(f"m3c view: open http://{host}:{server.get_port()} (Ctrl-C to stop)", flush=True)
        if ready is not None:
            ready(viewer)
        stop = stop or threading.Event()
        while not stop.is_set():
            started = time.monotonic()
            viewer.step()
            delay = 1.0 / (viewer.source.fps * float(viewer.speed.value)) - (time.monotonic() - started)
            stop.wait(max(delay, 0.001))
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
