"""A synthetic scene from m3c.eval.scenes turned into pipeline inputs: a rendered video of the true bodies, and
what the perception and odometry nodes would output (saved for `load` nodes), with the scene's errors.

The camera-local bodies are the true ones seen from each true camera with depth, orientation, pose and shape
errors; their cameras are given as patch (crop) cameras, so the local-tracks node converts them (CLIFF). Detections
are dropped where the scene dropped keypoints (gaps to interpolate). Odometry is the scene's: true rotations,
translations divided by the unknown scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.eval.scenes import make_scene
from m3c.io.video import VideoWriter
from m3c.nodes.load import save_outputs
from m3c.perception.boxes import full_to_crop_camera, process_boxes
from m3c.viz.scene import WorldView, overlay_frame

PERCEPTION = ("detections", "keypoints", "body", "tracking", "contacts", "cameras")


def write_scene_inputs(model, folder: Path, num_frames: int = 30, seed: int = 0, depth_bias: float = 1.05):
    """Writes folder/video.mp4 and one saved-outputs folder per perception node; returns the scene."""
    scene = make_scene(model, num_people=2, num_frames=num_frames, seed=seed)
    rng = np.random.default_rng(seed + 100)
    W, H = scene.image_size
    K = scene.cameras_true.intrinsics
    truth_cams = scene.cameras_true.world_from_cam

    # The video: the true bodies over a chequered ground, seen by the true camera.
    ground = WorldView(np.concatenate([t.transl for t in scene.truth]), truth_cams[:, :3, 3], 0.0, W, H)
    with VideoWriter(folder / "video.mp4", scene.fps, (W, H)) as writer:
        for i in range(num_frames):
            from m3c.viz.raster import Mesh, render
            from m3c.camera import to_camera

            background, _ = render([Mesh(to_camera(ground.ground.vertices, truth_cams[i]), ground.ground.faces,
                                         face_colours=ground.ground.face_colours, smooth=False, cull=False)],
                                   K, W, H, background=np.full((H, W, 3), 235, np.uint8))
            bodies = [(model.forward(np.concatenate([t.root_orient[i:i + 1, None], t.body_pose[i:i + 1]], 1),
                                     t.betas, t.transl[i:i + 1]).vertices[0], 7 + p)
                      for p, t in enumerate(scene.truth)]
            writer.write(overlay_frame(background, bodies, model.faces, truth_cams[i], K, alpha=1.0))

    rows = {name: [] for name in ("frame", "box", "score", "keypoints", "pose", "betas", "transl", "track_id",
                                  "contacts")}
    for p, (truth, init) in enumerate(zip(scene.truth, scene.init)):
        j0 = rest_root_joint(model, truth.betas)
        cam_from_world = np.linalg.inv(truth_cams)
        root_cam, transl_cam = transform_smpl(cam_from_world, truth.root_orient, truth.transl, j0)
        pose = np.concatenate([truth.root_orient[:, None], truth.body_pose], axis=1)
        vertices = model.forward(pose, truth.betas, truth.transl).vertices
        for i in range(num_frames):
            if not (init.keypoints[i, :, 2] > 0).any():
                continue  # the scene dropped this detection
            cam = vertices[i] @ cam_from_world[i, :3, :3].T + cam_from_world[i, :3, 3]
            uv = np.stack([K[0] * cam[:, 0] / cam[:, 2] + K[2], K[1] * cam[:, 1] / cam[:, 2] + K[3]], axis=1)
            rows["frame"].append(i)
            rows["box"].append([*uv.min(axis=0), *uv.max(axis=0)])
            rows["score"].append(0.9)
            rows["keypoints"].append(init.keypoints[i])
            noisy_root = Rotation.from_rotvec(0.05 * rng.normal(size=3)) * Rotation.from_rotvec(root_cam[i])
            rows["pose"].append(np.concatenate([noisy_root.as_rotvec()[None], init.body_pose[i]]))
            rows["betas"].append(init.betas)
            rows["transl"].append(transl_cam[i] * depth_bias * (1 + 0.02 * rng.normal()))
            rows["track_id"].append(p)
            rows["contacts"].append(truth.contacts[i])
    table = {k: np.asarray(v) for k, v in rows.items()}
    order = np.lexsort((np.arange(len(table["frame"])), table["frame"]))
    table = {k: v[order] for k, v in table.items()}
    square, _ = process_boxes(table["box"], (H, W), 5.0)  # what the boxes node will compute
    outputs = {
        "detections": {"frame": table["frame"].astype(np.int64), "box": table["box"].astype(np.float32),
                       "score": table["score"].astype(np.float32)},
        "keypoints": {"keypoints": table["keypoints"].astype(np.float32)},
        "body": {"pose": table["pose"], "betas": table["betas"],
                 "crop_cam": full_to_crop_camera(table["transl"], square.astype(np.float32), K)},
        "tracking": {"track_id": table["track_id"].astype(np.int64)},
        "contacts": {"joint_contacts": table["contacts"].astype(np.float32)},
        "cameras": {"world_from_cam": scene.cameras_vo.world_from_cam, "static": False, "source": "synthetic"},
    }
    for name, value in outputs.items():
        save_outputs(folder / name, {name: value})
    return scene


def scene_pipeline_yaml(folder: Path, intrinsics) -> str:
    """The default pipeline with the perception and odometry nodes replaced by `load` nodes."""
    load = "\n".join(f"  {name}:\n    type: load\n    config: {{path: {folder / name}, outputs: [{name}]}}"
                     for name in PERCEPTION if name != "cameras")
    return f"""
nodes:
  frames: {{}}
  camera:
    inputs: {{video: frames.video}}
    config: {{intrinsics: [{', '.join(str(float(v)) for v in intrinsics)}]}}
{load}
  vo:
    type: load
    config: {{path: {folder / 'cameras'}, outputs: [cameras]}}
  boxes:
    inputs: {{video: frames.video, detections: detections.detections}}
  local_tracks:
    inputs: {{video: frames.video, camera: camera.camera, detections: detections.detections, boxes: boxes.boxes,
             keypoints: keypoints.keypoints, body: body.body, tracking: tracking.tracking,
             contacts: contacts.contacts}}
  scale:
    inputs: {{tracks: local_tracks.tracks, cameras: vo.cameras}}
  ground:
    inputs: {{tracks: local_tracks.tracks, cameras: vo.cameras, scale: scale.scale}}
  lift:
    inputs: {{video: frames.video, camera: camera.camera, tracks: local_tracks.tracks, cameras: vo.cameras,
             scale: ground.scale, ground: ground.ground}}
    config: {{method: camera}}
  optimize:
    inputs: {{video: frames.video, camera: camera.camera, world: lift.world}}
  results:
    inputs: {{video: frames.video, camera: camera.camera, cameras: vo.cameras, scale: ground.scale,
             ground: ground.ground, world: lift.world, result: optimize.result}}
  overlay:
    inputs: {{video: frames.video, camera: camera.camera, result: optimize.result}}
  world_view:
    inputs: {{video: frames.video, camera: camera.camera, ground: ground.ground, result: optimize.result}}
  camera_plot:
    inputs: {{video: frames.video, result: optimize.result}}
"""
