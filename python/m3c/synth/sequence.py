"""One synthetic sequence, end to end: people from motion capture, a camera path, a static world, and the
rendered H.264 video with its ground truth, written once into a folder keyed by everything that shapes them.

Ground truth (truth.npz, world frame y up, ground y = 0, metres; P people, T frames, B betas):
  fps (the video's: its time), slow_motion (the mocap played this many times slower: real time is fps x
  slow_motion frames a second), image_size (W, H), intrinsics (4,) fx fy cx cy, world_from_cam (T, 4, 4), ground_normal (3,),
  ground_offset (); per person: root_orient (P, T, 3), body_pose (P, T, 23, 3), transl (P, T, 3), betas (P, B),
  joints (P, T, 24, 3) world, keypoints_2d (P, T, 17, 2) projected COCO-17 keypoints, keypoints_in_image
  (P, T, 17), contacts (P, T, 4) planted ankles/feet (CONTACT_JOINTS), visible_pixels (P, T) pixels of the person
  in the frame, silhouette_pixels (P, T) pixels the person covers when drawn alone (occlusion = 1 - visible /
  silhouette); crowd_joints (C, T, 24, 3) the unscored background walkers' world joints (C = 0 without a crowd).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from m3c.body import BodyModel
from m3c.camera import project, to_camera
from m3c.eval.retarget import RetargetedMotion
from m3c.io.atomic import atomic_path, save_npz_atomic
from m3c.synth.cameras import CAMERA_KINDS, EXTRA_CAMERA_KINDS, camera_path
from m3c.synth.people import Person, face_colours, place_crowd, place_people, true_contacts, vertex_parts
from m3c.synth.render import RenderedFrame, Renderer
from m3c.synth.world import FLOORS, StaticScene, make_scene

GENERATOR_VERSION = 1
CHUNK = 24  # frames posed at once


@dataclass(frozen=True)
class SequenceSpec:
    index: int
    camera: str
    num_people: int
    num_frames: int = 150
    fps: float = 30.0
    width: int = 960
    height: int = 540
    seed: int = 0
    supersample: int = 1
    # Beyond the default set (m3c.eval.video_benchmark's hard suite); their defaults leave a sequence as it was:
    slow_motion: float = 1.0  # the mocap played this many times slower (the video's fps unchanged)
    floor: str = "textured"  # m3c.synth.world.FLOORS
    degrade: bool = False  # phone optics: DEGRADE's blur, sensor noise and low-bitrate H.264
    crowd: int = 0  # unscored walkers behind and in front of the scored people (m3c.synth.people.place_crowd)

    @property
    def name(self) -> str:
        extra = "".join([f"_slow{self.slow_motion:g}" if self.slow_motion != 1.0 else "",
                         f"_{self.floor}" if self.floor != "textured" else "", "_degraded" if self.degrade else "",
                         f"_crowd{self.crowd}" if self.crowd else ""])
        return f"seq{self.index:02d}_{self.camera}_{self.num_people}p{extra}"

    def key(self) -> dict:
        """The fields that shape the sequence, the hard suite's only where they differ from their defaults (the
        default set's folders keep their names)."""
        out = asdict(self)
        for name, default in EXTRA_DEFAULTS.items():
            if out[name] == default:
                del out[name]
        return out

    def validate(self) -> None:
        if self.num_frames < 2:
            raise ValueError(f"a sequence needs at least 2 frames, got {self.num_frames}")
        if not 1 <= self.num_people <= 3:
            raise ValueError(f"1 to 3 people per sequence, got {self.num_people}")
        if self.width < 64 or self.height < 64 or self.width % 2 or self.height % 2:
            raise ValueError(
                f"image size must be even and at least 64 x 64 (H.264), got {self.width} x {self.height}"
            )
        if self.fps <= 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if not (np.isfinite(self.slow_motion) and 1.0 <= self.slow_motion <= 16.0):
            raise ValueError(f"slow_motion must be within 1-16 (times slower than real time), got "
                             f"{self.slow_motion}")
        if not 0 <= self.crowd <= MAX_CROWD:
            raise ValueError(f"crowd must be 0-{MAX_CROWD} walkers, got {self.crowd}")
        if self.floor not in FLOORS:
            raise ValueError(f"floor must be one of {', '.join(FLOORS)}, got {self.floor!r}")
        if self.camera not in CAMERA_KINDS + EXTRA_CAMERA_KINDS:
            raise ValueError(f"unknown camera kind {self.camera!r}")


EXTRA_DEFAULTS = {"slow_motion": 1.0, "floor": "textured", "degrade": False, "crowd": 0}
MAX_CROWD = 40
# Phone optics of a degraded sequence: Gaussian blur (pixels), sensor noise (8-bit levels, per pixel and channel)
# and the H.264 constant rate factor (the default set's 16 is near lossless; 30 is a phone's streaming quality).
DEGRADE = {"blur_px": 1.0, "noise_levels": 4.0, "crf": 30}


def slowed(clip: RetargetedMotion, factor: float) -> RetargetedMotion:
    """The clip played `factor` times slower at its frame rate: frame j shows time j / factor of the original
    (translations interpolated linearly, every joint rotation by slerp)."""
    if factor == 1.0:
        return clip
    from scipy.spatial.transform import Rotation

    n = clip.num_frames
    times = np.arange(int(np.floor((n - 1) * factor)) + 1) / factor
    i0 = np.minimum(np.floor(times).astype(int), n - 2)
    w = times - i0
    transl = clip.transl[i0] * (1 - w)[:, None] + clip.transl[i0 + 1] * w[:, None]
    pose = clip.pose()  # (n, 24, 3)
    r0 = Rotation.from_rotvec(pose[i0].reshape(-1, 3))
    r1 = Rotation.from_rotvec(pose[i0 + 1].reshape(-1, 3))
    step = (r0.inv() * r1).as_rotvec() * np.repeat(w, pose.shape[1])[:, None]
    pose = (r0 * Rotation.from_rotvec(step)).as_rotvec().reshape(len(times), -1, 3)
    return replace(clip, transl=transl, root_orient=pose[:, 0], body_pose=pose[:, 1:],
                   fit_error_mm=clip.fit_error_mm[np.round(times).astype(int)],
                   info={**clip.info, "slow_motion": float(factor)})


def degrade_frame(image: np.ndarray, rng) -> np.ndarray:
    """A rendered BGR uint8 frame through DEGRADE's blur and sensor noise (the bitrate is the writer's)."""
    import cv2

    blurred = cv2.GaussianBlur(image, (0, 0), DEGRADE["blur_px"]).astype(np.float32)
    noisy = blurred + DEGRADE["noise_levels"] * rng.standard_normal(image.shape).astype(np.float32)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


@dataclass
class SyntheticVideo:
    spec: SequenceSpec
    folder: Path
    video: Path
    truth_path: Path
    render_seconds: float  # 0 when it came from the cache

    def truth(self) -> dict:
        with np.load(self.truth_path) as z:
            return {k: z[k] for k in z.files}

    def meta(self) -> dict:
        return json.loads((self.folder / "meta.json").read_text())


def _digest(model: BodyModel, clips: list[RetargetedMotion], spec: SequenceSpec) -> str:
    h = hashlib.sha1()
    h.update(
        json.dumps(
            {"version": GENERATOR_VERSION, "spec": spec.key(), "model": getattr(model.data, "name", "")},
            sort_keys=True,
        ).encode()
    )
    for clip in clips:
        for a in (clip.transl, clip.root_orient, clip.body_pose, clip.betas):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()[:10]


def _video_writer(path: Path, width: int, height: int, fps: float, crf: int = 16):
    try:
        import imageio_ffmpeg
    except ImportError as err:
        raise ImportError(
            "writing H.264 videos needs imageio-ffmpeg (pip install imageio-ffmpeg; it is in m3c's "
            "dependencies)"
        ) from err
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (width, height),
        fps=fps,
        codec="libx264",
        pix_fmt_in="bgr24",
        output_params=["-crf", str(crf), "-preset", "fast"],
        macro_block_size=2,
        ffmpeg_log_level="error",
    )
    writer.send(None)
    return writer


def build_people(model: BodyModel, clips: list[RetargetedMotion], spec: SequenceSpec, rng) -> list[Person]:
    return place_people(
        model,
        [slowed(c, spec.slow_motion) for c in clips],
        spec.num_people,
        spec.num_frames,
        rng,
        travelling_first=spec.camera in ("follow", "tracking"),
    )


def make_video(
    model: BodyModel,
    clips: list[RetargetedMotion],
    spec: SequenceSpec,
    out_dir: str | Path,
    log=None,
    progress=None,
) -> SyntheticVideo:
    """The sequence's folder under out_dir (video.mp4, truth.npz, meta.json), rendered unless already there."""
    spec.validate()
    folder = Path(out_dir) / f"{spec.name}-{_digest(model, clips, spec)}"
    video, truth_path, meta = folder / "video.mp4", folder / "truth.npz", folder / "meta.json"
    if video.is_file() and truth_path.is_file() and meta.is_file():
        return SyntheticVideo(spec, folder, video, truth_path, 0.0)
    start = time.perf_counter()
    render_video(model, clips, spec, folder, progress)
    seconds = time.perf_counter() - start
    if log:
        log(
            f"{spec.name}: rendered {spec.num_frames} frames in {seconds:.1f} s "
            f"({spec.num_frames / seconds:.1f} frames/s) -> {folder}"
        )
    return SyntheticVideo(spec, folder, video, truth_path, seconds)


@dataclass
class SequenceSetup:
    """Everything that fixes a sequence's frames: people, camera, world, looks. frame(i) renders one."""

    model: BodyModel
    spec: SequenceSpec
    people: list[Person]
    joints: np.ndarray  # (P, n, 24, 3) world
    crowd: list[Person]  # unscored walkers, drawn after the people (their ids P, P + 1, ...)
    crowd_joints: np.ndarray  # (C, n, 24, 3) world
    world_from_cam: np.ndarray  # (n, 4, 4)
    intrinsics: np.ndarray  # (4,)
    camera_info: dict
    scene: StaticScene
    albedo: list[np.ndarray]  # (F, 3) per person, then per crowd walker
    renderer: Renderer

    def bodies(self, a: int, b: int) -> list[np.ndarray]:
        """Each person's, then each crowd walker's, world vertices (b - a, V, 3) over frames a..b-1."""
        return [self.model.forward(p.pose()[a:b], p.betas, p.transl[a:b]).vertices
                for p in self.people + self.crowd]

    def frame(self, i: int, vertices: list[np.ndarray] | None = None, full: bool = True) -> RenderedFrame:
        """Frame i (vertices: each person's and crowd walker's (V, 3) at frame i, else posed here); full=False:
        people only."""
        faces = np.asarray(self.model.faces, dtype=np.int32)
        vertices = vertices if vertices is not None else [v[0] for v in self.bodies(i, i + 1)]
        return self.renderer.render(
            self.world_from_cam[i],
            self.intrinsics,
            self.scene.meshes,
            [(v, faces, a) for v, a in zip(vertices, self.albedo)],
            full,
            self.scene.gloss,
        )


def setup_sequence(model: BodyModel, clips: list[RetargetedMotion], spec: SequenceSpec) -> SequenceSetup:
    """The seeded people, camera path and world of a sequence (deterministic for the spec and clips)."""
    spec.validate()
    rng = np.random.default_rng([spec.seed, spec.index])
    n, P = spec.num_frames, spec.num_people
    people = build_people(model, clips, spec, rng)
    joints = np.stack([model.joints(p.pose(), p.betas, p.transl) for p in people])  # (P, n, 24, 3)
    world_from_cam, intrinsics, camera_info = camera_path(
        spec.camera, joints, spec.fps, (spec.width, spec.height), rng
    )
    crowd = []
    if spec.crowd:  # its own generator: the other draws stay as without a crowd
        crowd_rng = np.random.default_rng([spec.seed, spec.index, 2])
        crowd = place_crowd(model, [slowed(c, spec.slow_motion) for c in clips], spec.crowd, n, spec.fps,
                            crowd_rng, world_from_cam, np.radians(camera_info["hfov_deg"]), people)
    cam_xz = world_from_cam[:, :3, 3][:, [0, 2]]
    pelvis_xz = joints[:, :, 0][..., [0, 2]]
    sight = [(cam_xz[i], pelvis_xz[p, i]) for i in range(0, n, max(1, n // 12)) for p in range(P)]
    crowd_joints = np.stack([model.joints(p.pose(), p.betas, p.transl) for p in crowd]) if crowd \
        else np.zeros((0, n, 24, 3))
    walkers_xz = crowd_joints[:, :, 0, [0, 2]].reshape(-1, 2)  # kept clear of objects, as the people are
    scene = make_scene(rng, np.concatenate([pelvis_xz.reshape(-1, 2), walkers_xz]), cam_xz, sight,
                       floor=spec.floor)
    parts = vertex_parts(model)
    albedo = [face_colours(model, parts, p.look, rng) for p in people]
    if crowd:
        albedo += [face_colours(model, parts, p.look, crowd_rng) for p in crowd]
    renderer = Renderer(scene.textures, spec.width, spec.height, spec.supersample)
    return SequenceSetup(
        model, spec, people, joints, crowd, crowd_joints, world_from_cam, intrinsics, camera_info, scene,
        albedo, renderer
    )


def render_video(
    model: BodyModel, clips: list[RetargetedMotion], spec: SequenceSpec, folder: Path, progress=None
) -> None:
    """Generates and renders the sequence into `folder`; meta.json is written last (it marks a complete folder)."""
    setup = setup_sequence(model, clips, spec)
    people, world_from_cam, intrinsics = setup.people, setup.world_from_cam, setup.intrinsics
    n, P, W, H = spec.num_frames, spec.num_people, spec.width, spec.height
    alone = Renderer([], W, H, spec.supersample)  # ids sampled where the full frame samples them
    faces = np.asarray(model.faces, dtype=np.int32)
    regressor = model.coco17_regressor()
    truth = {
        "keypoints_2d": np.zeros((P, n, 17, 2), np.float32),
        "keypoints_in_image": np.zeros((P, n, 17), bool),
        "visible_pixels": np.zeros((P, n), np.int64),
        "silhouette_pixels": np.zeros((P, n), np.int64),
    }
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(folder / "video.mp4", suffix=".mp4") as tmp:
        writer = _video_writer(tmp, W, H, spec.fps, DEGRADE["crf"] if spec.degrade else 16)
        noise_rng = np.random.default_rng([spec.seed, spec.index, 1])
        try:
            for a in range(0, n, CHUNK):
                b = min(n, a + CHUNK)
                verts = setup.bodies(a, b)
                kps = [model.keypoints(regressor, p.pose()[a:b], p.betas, p.transl[a:b]) for p in people]
                for i in range(a, b):
                    frame = setup.frame(i, [v[i - a] for v in verts])
                    image = degrade_frame(frame.image, noise_rng) if spec.degrade else frame.image
                    writer.send(np.ascontiguousarray(image))
                    for p in range(P):
                        truth["visible_pixels"][p, i] = int((frame.ids == p).sum())
                        own = alone.render(
                            world_from_cam[i],
                            intrinsics,
                            [],
                            [(verts[p][i - a], faces, setup.albedo[p])],
                            full=False,
                        )
                        truth["silhouette_pixels"][p, i] = int((own.ids == 0).sum())
                        uv, inside = project_points(kps[p][i - a], world_from_cam[i], intrinsics, W, H)
                        truth["keypoints_2d"][p, i] = uv
                        truth["keypoints_in_image"][p, i] = inside
                    if progress is not None:
                        progress.update()
        finally:
            writer.close()
    arrays = {
        "fps": np.float64(spec.fps),
        "slow_motion": np.float64(spec.slow_motion),  # real time: fps x slow_motion frames a second
        "image_size": np.array([W, H], np.int32),
        "intrinsics": intrinsics.astype(np.float64),
        "world_from_cam": world_from_cam.astype(np.float64),
        "ground_normal": np.array([0.0, 1.0, 0.0]),
        "ground_offset": np.float64(0.0),
        "root_orient": np.stack([p.root_orient for p in people]),
        "body_pose": np.stack([p.body_pose for p in people]),
        "transl": np.stack([p.transl for p in people]),
        "betas": np.stack([p.betas for p in people]),
        "joints": setup.joints,
        "contacts": np.stack([true_contacts(model, p.pose(), p.betas, p.transl) for p in people]),
        "crowd_joints": setup.crowd_joints.astype(np.float32),
        **truth,
    }
    save_npz_atomic(folder / "truth.npz", **arrays)
    meta = {
        "name": spec.name,
        "spec": asdict(spec),
        "generator_version": GENERATOR_VERSION,
        "body_model": getattr(model.data, "name", ""),
        "camera": setup.camera_info,
        "people": [
            {
                "clip": p.clip,
                "start_frame": int(p.start),
                "look": {k: [round(float(c), 3) for c in v] for k, v in p.look.colours.items()},
            }
            for p in people
        ],
        "crowd": [{"clip": p.clip, "start_frame": int(p.start)} for p in setup.crowd],
        "objects": [
            {
                "kind": o["kind"],
                "centre_xz": [float(v) for v in o["centre"]],
                "size": [float(v) for v in o["size"]],
            }
            for o in setup.scene.objects
        ],
        "world": "y up, metres, ground y = 0; cameras OpenCV, world_from_cam",
    }
    with atomic_path(folder / "meta.json") as tmp:
        tmp.write_text(json.dumps(meta, indent=1) + "\n")


def project_points(points, world_from_cam, intrinsics, width, height):
    """(K, 3) world points -> (K, 2) pixels (-1 behind the camera) and (K,) inside the image."""
    cam = to_camera(points, world_from_cam)
    cam[:, 2] = np.where(cam[:, 2] > 1e-6, cam[:, 2], np.nan)  # behind the camera: no pixel
    uv = project(cam, intrinsics)
    inside = (
        np.isfinite(uv).all(-1)
        & (uv[:, 0] >= 0)
        & (uv[:, 0] <= width - 1)
        & (uv[:, 1] >= 0)
        & (uv[:, 1] <= height - 1)
    )
    return np.nan_to_num(uv, nan=-1.0), inside
