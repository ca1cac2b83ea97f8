"""M3C's results in the files peer methods' demos write, so that their viewers and evaluation scripts read them.

Read from the peers' code (key names, shapes, frames):
- WHAM (yohanshin/WHAM, demo.py --save_pkl): wham_output.pkl, a joblib/pickle dict {track id: {...}} with
  pose (n, 72) [root orientation in the camera, 23 body joints], trans (n, 3) SMPL translation in the camera,
  pose_world (n, 72), trans_world (n, 3) in WHAM's gravity-aligned y-up world, betas (n, 10), verts (n, 6890, 3)
  camera-frame SMPL vertices, frame_ids (n,) video frame indices.
- SLAHMR (vye16/slahmr, optim/output.py, vis/output.py): <phase>/<seq>_<iter>_world_results.npz with trans,
  root_orient (B, T, 3), pose_body (B, T, 63) (SMPL-H's 21 body joints), betas (B, 16), cam_R (B, T, 3, 3) and
  cam_t (B, T, 3) world-to-camera, intrins (4,) fx, fy, cx, cy, floor_plane (1, 3) (normal times offset),
  floor_idcs (B,), world_scale (1, 1); track_info.json with each track's row and visibility mask. The world is
  the first camera's frame (OpenCV: y down), as SLAHMR's SLAM world is; all tracks span every frame.
- GVHMR (zju3dv/GVHMR, tools/demo/demo.py): hmr4d_results.pt (torch.save) with smpl_params_global and
  smpl_params_incam, each {body_pose (L, 63), betas (L, 10), global_orient (L, 3), transl (L, 3)}, and K_fullimg
  (L, 3, 3); the global frame is gravity-aligned y up. GVHMR follows one person: one folder per track.

Shape parameters are the ones of the body model the run used; they mean what the peers expect (SMPL's) only when
that model was SMPL (`m3c run --body-model`). WHAM's verts are written only for a 6890-vertex (SMPL) model.
"""

from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import numpy as np

from m3c.body.transform import transform_smpl
from m3c.export.source import ExportSource, TrackMotion
from m3c.io.atomic import atomic_path, save_npz_atomic

SMPL_VERTICES = 6890
SLAHMR_BETAS = 16          # SLAHMR's SMPL-H has 16 shape components
BODY_JOINTS_21 = 21        # SMPL-H/SMPL-X body joints: SMPL's 23 without the two hand joints


def _camera_pose(source: ExportSource, track: TrackMotion) -> tuple[np.ndarray, np.ndarray]:
    """The track's (root orientation, SMPL translation) in each of its frames' cameras (results.npz's cam_*)."""
    p = track.index
    return (source.arrays["cam_root_orient"][p, track.frames].astype(np.float64),
            source.arrays["cam_transl"][p, track.frames].astype(np.float64))


def _seq_name(source: ExportSource) -> str:
    stem = Path(source.summary["video"]["name"]).stem or "m3c"
    return re.sub(r"[^A-Za-z0-9.-]+", "-", stem)  # SLAHMR splits result file names at underscores


def export_wham(source: ExportSource, out: Path) -> list[Path]:
    """out/wham_output.pkl (or `out` when it ends in .pkl)."""
    path = out if out.suffix == ".pkl" else out / "wham_output.pkl"
    model = source.model
    frame_ids = source.arrays["frame_ids"]
    results = {}
    for track in source.tracks:
        n = len(track.frames)
        cam_root, cam_transl = _camera_pose(source, track)
        pose_cam = np.concatenate([cam_root, track.pose[:, 1:].reshape(n, -1)], axis=1)
        entry = {"pose": pose_cam.astype(np.float32), "trans": cam_transl.astype(np.float32),
                 "pose_world": track.pose.reshape(n, -1).astype(np.float32),
                 "trans_world": track.transl.astype(np.float32),
                 "betas": np.tile(track.betas, (n, 1)).astype(np.float32),
                 "frame_ids": frame_ids[track.frames].astype(np.int64)}
        if model.num_vertices == SMPL_VERTICES:
            entry["verts"] = model.forward(pose_cam.reshape(n, 24, 3), track.betas, cam_transl).vertices.astype(
                np.float32)
        results[track.track_id] = entry
    with atomic_path(path) as tmp:
        tmp.write_bytes(pickle.dumps(results, protocol=4))
    return [path]


def _fill_outside(values: np.ndarray, frames: np.ndarray, num_frames: int) -> np.ndarray:
    """(n, ...) values of a track's frames -> (num_frames, ...), holding the first/last value outside them
    (SLAHMR pads tracks with their end values; track_info.json's vis_mask says which frames are real)."""
    index = np.clip(np.arange(num_frames), frames[0], frames[-1]) - frames[0]
    return values[index]


def export_slahmr(source: ExportSource, out: Path) -> list[Path]:
    """out/motion_chunks/<seq>_000000_world_results.npz and out/track_info.json."""
    arrays, T = source.arrays, source.num_frames
    world_from_cam = arrays["world_from_cam"].astype(np.float64)
    cam0_from_world = np.linalg.inv(world_from_cam[0])
    cam_from_slahmr = np.linalg.inv(world_from_cam) @ world_from_cam[0]   # SLAHMR's world: camera 0
    fields = {"trans": [], "root_orient": [], "pose_body": [], "betas": []}
    vis_masks = {}
    for i, track in enumerate(source.tracks):
        root, transl = transform_smpl(cam0_from_world, track.pose[:, 0], track.transl, track.rest_joints[0])
        fields["trans"].append(_fill_outside(transl, track.frames, T))
        fields["root_orient"].append(_fill_outside(root, track.frames, T))
        body = track.pose[:, 1:1 + BODY_JOINTS_21].reshape(len(track.frames), -1)
        fields["pose_body"].append(_fill_outside(body, track.frames, T))
        betas = np.zeros(SLAHMR_BETAS)
        betas[:min(len(track.betas), SLAHMR_BETAS)] = track.betas[:SLAHMR_BETAS]
        fields["betas"].append(betas)
        vis_masks[track.track_id] = {"index": i, "vis_mask": [int(v) for v in arrays["visible"][track.index]]}
    B = len(source.tracks)
    result = {k: np.stack(v).astype(np.float32) for k, v in fields.items()}
    result["cam_R"] = np.broadcast_to(cam_from_slahmr[:, :3, :3], (B, T, 3, 3)).astype(np.float32)
    result["cam_t"] = np.broadcast_to(cam_from_slahmr[:, :3, 3], (B, T, 3)).astype(np.float32)
    result["intrins"] = source.intrinsics.astype(np.float32)
    result["world_scale"] = np.ones((1, 1), np.float32)   # cam_t is already in metres
    if source.ground_found:
        # The ground y = 0 in the results' world; in camera 0: normal n' = R n through the point A (0, 0, 0).
        normal = cam0_from_world[:3, :3] @ np.array([0.0, 1.0, 0.0])
        offset = float(normal @ cam0_from_world[:3, 3])
        result["floor_plane"] = (normal * offset)[None].astype(np.float32)
        result["floor_idcs"] = np.zeros(B, dtype=np.int64)
    npz = out / "motion_chunks" / f"{_seq_name(source)}_{0:06d}_world_results.npz"
    npz.parent.mkdir(parents=True, exist_ok=True)
    save_npz_atomic(npz, **result)
    info = out / "track_info.json"
    with atomic_path(info) as tmp:
        tmp.write_text(json.dumps({"tracks": {str(k): v for k, v in vis_masks.items()},
                                   "meta": {"seq_interval": [0, T], "data_interval": [0, T]}}))
    return [npz, info]


def export_gvhmr(source: ExportSource, out: Path) -> list[Path]:
    """out/track<ID>/hmr4d_results.pt per track (torch.save, as GVHMR's demo writes it)."""
    try:
        import torch
    except ImportError:
        raise ImportError("GVHMR's layout is a torch file: install torch (pip install m3c[torch])") from None
    fx, fy, cx, cy = source.intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    paths = []
    for track in source.tracks:
        n = len(track.frames)
        cam_root, cam_transl = _camera_pose(source, track)

        def params(root, transl):
            return {"body_pose": torch.as_tensor(track.pose[:, 1:1 + BODY_JOINTS_21].reshape(n, -1),
                                                 dtype=torch.float32),
                    "betas": torch.as_tensor(np.tile(track.betas[:10], (n, 1)), dtype=torch.float32),
                    "global_orient": torch.as_tensor(root, dtype=torch.float32),
                    "transl": torch.as_tensor(transl, dtype=torch.float32)}

        pred = {"smpl_params_global": params(track.pose[:, 0], track.transl),
                "smpl_params_incam": params(cam_root, cam_transl),
                "K_fullimg": torch.as_tensor(np.tile(K, (n, 1, 1)), dtype=torch.float32),
                "m3c_frame_ids": torch.as_tensor(source.arrays["frame_ids"][track.frames])}
        path = out / f"track{track.track_id}" / "hmr4d_results.pt"
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            torch.save(pred, tmp)
        paths.append(path)
    return paths

