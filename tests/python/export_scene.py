"""A small result folder for the export and viewer tests: two people walking in front of a camera that moves,
written by the same code as `m3c run` (m3c.nodes.results.build_results) from known parameters."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.camera import WorldCameras
from m3c.io.manifest import seal
from m3c.io.npz import write_npz
from m3c.nodes.results import build_results

FPS = 10.0
WIDTH, HEIGHT = 160, 120
INTRINSICS = [150.0, 150.0, 79.5, 59.5]


def look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """world_from_cam (4, 4) of an OpenCV camera at `centre` looking at `target`, world y up."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, -1.0, 0.0])   # image x to the right when y (image down) points to world -y
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = centre
    return T


def make_tracks(num_frames: int, seed: int):
    """Two tracks: one over every frame, one over frames 3..num_frames-3, with walking-like random poses."""
    rng = np.random.default_rng(seed)
    spans = [(0, num_frames), (3, num_frames - 2)]
    tracks = []
    for k, (first, stop) in enumerate(spans):
        n = stop - first
        t = np.arange(n) / FPS
        body_pose = 0.25 * rng.normal(size=(23, 3)) + 0.4 * np.sin(2.0 * t)[:, None, None] * rng.normal(size=(23, 3))
        heading = 0.3 * k + 0.5 * t
        root = (Rotation.from_euler("y", heading[:, None]) * Rotation.from_euler("x", 0.1 * np.sin(3.0 * t)[:, None])).as_rotvec()
        transl = np.stack([-0.6 + 1.2 * k + 0.3 * t, 0.9 + 0.02 * np.sin(4.0 * t), 3.0 + 0.5 * t], axis=1)
        tracks.append({"track_id": 4 + 3 * k, "first_frame": first, "num_frames": n, "root_orient": root,
                       "body_pose": body_pose, "betas": rng.normal(scale=0.8, size=10), "transl": transl,
                       "visible": np.arange(n) % 5 != 2, "keypoints": np.zeros((n, 17, 3)),
                       "contacts": rng.uniform(size=(n, 4))})
    return tracks


def make_hands(tracks: list[dict], seed: int) -> dict:
    """The hands node's output for the tracks: random finger poses and wrist corrections, no hand in a few
    frames."""
    rng = np.random.default_rng(seed)
    out = []
    for track in tracks:
        n = track["num_frames"]
        hand_pose = rng.normal(scale=0.3, size=(n, 2, 15, 3))
        correction = rng.normal(scale=0.1, size=(n, 2, 3))
        keypoints = np.concatenate([rng.uniform(0, 100, (n, 2, 21, 2)), np.full((n, 2, 21, 1), 0.9)], axis=-1)
        missing = np.arange(n) % 4 == 1
        for array in (hand_pose, correction, keypoints):
            array[missing, 1] = np.nan
        out.append({"track_id": track["track_id"], "first_frame": track["first_frame"], "num_frames": n,
                    "keypoints": keypoints, "hand_pose": hand_pose, "wrist_correction": correction})
    return {"enabled": True, "reason": None, "seconds": 1.0, "frames": 10, "hand_frames": 10, "tracks": out}


def write_results(folder: Path, model, num_frames: int = 12, seed: int = 0, ground: bool = True,
                  hands: bool = False) -> Path:
    """Writes folder/results.npz and results.json under a complete manifest; returns folder. hands: with
    finger poses (make_hands)."""
    folder.mkdir(parents=True, exist_ok=True)
    tracks = make_tracks(num_frames, seed)
    centres = np.stack([np.linspace(0.0, 0.8, num_frames), np.full(num_frames, 1.5), np.zeros(num_frames)], 1)
    world_from_cam = np.stack([look_at(c, np.array([0.2, 0.9, 3.5])) for c in centres])
    video = {"num_frames": num_frames, "frame_ids": np.arange(num_frames) * 2, "fps": FPS, "width": WIDTH,
             "height": HEIGHT, "name": "synthetic.mp4", "start": 0, "stop": 2 * num_frames, "step": 2,
             "times": np.arange(num_frames) / FPS}
    # The world lift: a little off the final motion (newer result schemas also store its pose, shape, cameras).
    cameras = WorldCameras(world_from_cam[:, :3, :3], world_from_cam[:, :3, 3], 1.0).as_dict()
    world = {"method": "test", "cameras": cameras,
             "tracks": [{"track_id": t["track_id"], "root_orient": t["root_orient"] + 0.01,
                         "transl": t["transl"] + 0.05, "body_pose": t["body_pose"] + 0.02, "betas": t["betas"]}
                        for t in tracks]}
    result = {"tracks": tracks, "cameras": cameras, "camera_scale": 1.0,
              "camera_offset": np.zeros(3), "optimized": True, "stopped_early": False, "stages": []}
    arrays, summary = build_results(model, video, {"intrinsics": INTRINSICS, "source": "test"},
                                    {"static": False, "source": "test"}, {"source": "test"},
                                    {"up_source": "ground" if ground else "camera", "contact_points": 0}, world,
                                    result, {}, hands=make_hands(tracks, seed) if hands else None)
    write_npz(folder / "results.npz", arrays)
    (folder / "results.json").write_text(json.dumps(summary, indent=1) + "\n")
    seal(folder, ["results.npz", "results.json"])  # as `m3c run` would publish them
    return folder
