"""A synthetic scene from m3c.eval.scenes turned into pipeline inputs: a rendered video of the true bodies, and
what the perception and odometry nodes would output (saved for `load` nodes), with the scene's errors.

The camera-local bodies are the true ones seen from each true camera with depth, orientation, pose and shape
errors; their cameras are given as patch (crop) cameras, so the local-tracks node converts them (CLIFF). A track
leaves out the frames where the scene dropped keypoints (gaps to interpolate). Odometry is the scene's: true
rotations, translations divided by the unknown scale.
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


def write_scene_inputs(model, folder: Path, num_frames: int = 30, seed: int = 0, depth_bias: float = 1.05):
    """Writes folder/video.mp4, folder/perception (perception's tracks, m3c.perception.handover) and
    folder/cameras (the odometry's output), saved outputs for `load` nodes; returns the scene."""
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

    tracks = []
    for p, (truth, init) in enumerate(zip(scene.truth, scene.init)):
        j0 = rest_root_joint(model, truth.betas)
        cam_from_world = np.linalg.inv(truth_cams)
        root_cam, transl_cam = transform_smpl(cam_from_world, truth.root_orient, truth.transl, j0)
        pose = np.concatenate([truth.root_orient[:, None], truth.body_pose], axis=1)
        vertices = model.forward(pose, truth.betas, truth.transl).vertices
        rows = {name: [] for name in ("frame", "box", "keypoints", "pose", "transl", "contacts")}
        for i in range(num_frames):
            if not (init.keypoints[i, :, 2] > 0).any():
                continue  # the scene dropped this detection
            cam = vertices[i] @ cam_from_world[i, :3, :3].T + cam_from_world[i, :3, 3]
            uv = np.stack([K[0] * cam[:, 0] / cam[:, 2] + K[2], K[1] * cam[:, 1] / cam[:, 2] + K[3]], axis=1)
            rows["frame"].append(i)
            rows["box"].append([*uv.min(axis=0), *uv.max(axis=0)])
            rows["keypoints"].append(init.keypoints[i])
            noisy_root = Rotation.from_rotvec(0.05 * rng.normal(size=3)) * Rotation.from_rotvec(root_cam[i])
            rows["pose"].append(np.concatenate([noisy_root.as_rotvec()[None], init.body_pose[i]]))
            rows["transl"].append(transl_cam[i] * depth_bias * (1 + 0.02 * rng.normal()))
            rows["contacts"].append(truth.contacts[i])
        n = len(rows["frame"])
        box = np.asarray(rows["box"], dtype=np.float32)
        square = process_boxes(box, (H, W), 5.0)[0].astype(np.float32)  # as perception hands them over
        tracks.append({"track_id": p, "frame": np.asarray(rows["frame"], dtype=np.int64), "box": box,
                       "square": square, "score": np.full(n, 0.9, np.float32),
                       "keypoints": np.asarray(rows["keypoints"], dtype=np.float32),
                       "pose": np.asarray(rows["pose"]), "betas": np.tile(init.betas, (n, 1)),
                       "crop_cam": full_to_crop_camera(np.asarray(rows["transl"]), square, K),
                       "contacts": np.asarray(rows["contacts"], dtype=np.float32)})
    save_outputs(folder / "perception", {"tracks": {"tracks": tracks}})
    save_outputs(folder / "cameras", {"cameras": {"world_from_cam": scene.cameras_vo.world_from_cam, "static": False,
                                                  "source": "synthetic"}})
    return scene


def scene_pipeline_yaml(folder: Path, intrinsics) -> str:
    """The default pipeline with the perception and odometry nodes replaced by `load` nodes."""
    return f"""
nodes:
  frames: {{}}
  camera:
    inputs: {{video: frames.video}}
    config: {{intrinsics: [{', '.join(str(float(v)) for v in intrinsics)}]}}
  perception:
    type: load
    config: {{path: {folder / 'perception'}, outputs: [tracks]}}
  vo:
    type: load
    config: {{path: {folder / 'cameras'}, outputs: [cameras]}}
  local_tracks:
    inputs: {{video: frames.video, camera: camera.camera, tracks: perception.tracks}}
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
