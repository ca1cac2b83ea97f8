"""The exports opened in real Blender (the bpy module, run in its own environment): at every frame the imported
joints' world positions match results.npz's world_joints, and the imported camera's world matrix matches
world_from_cam, after Blender's documented axis change (Blender (x, y, z) = M3C (x, -z, y))."""

from __future__ import annotations

import json

import numpy as np
import pytest

from export_scene import write_results
from m3c.body import default_body_model
from m3c.export import export_results, load_source
from m3c.export.blender import BlenderUnavailable, blender_python, run_blender

try:
    blender_python()
    BLENDER_MISSING = ""
except BlenderUnavailable as err:
    BLENDER_MISSING = str(err)

pytestmark = pytest.mark.skipif(bool(BLENDER_MISSING), reason=f"Blender (bpy) absent: {BLENDER_MISSING}")

BLENDER_FROM_M3C = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
GL_FROM_CV = np.diag([1.0, -1.0, -1.0])
MM = 1e-3


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib")
    return write_results(tmp_path_factory.mktemp("blender") / "out", default_body_model())


def _sample(path, tmp_path, fps, last):
    out = tmp_path / f"{path.name}.json"
    run_blender("sample", path, fps, 0, last, out)
    return json.loads(out.read_text())


def _check_joints(sampled, source, names_of, frame_offset):
    armatures = sampled["armatures"]
    assert len(armatures) == len(source.tracks)
    for track in source.tracks:
        bones = names_of(armatures, track)
        joints = np.array([bones[name] for name in source.joint_names]).transpose(1, 0, 2)  # frames x 24 x 3
        imported = joints[track.frames + frame_offset]
        np.testing.assert_allclose(imported, track.world_joints @ BLENDER_FROM_M3C.T, atol=MM)


def _check_camera(sampled, source):
    # The vertical field of view is the video's; the horizontal one follows Blender's render resolution.
    assert sampled["camera_fov"]["video_camera"][1] == pytest.approx(source.vertical_fov, abs=1e-6)
    matrices = np.array(sampled["cameras"]["video_camera"])
    world_from_cam = source.arrays["world_from_cam"].astype(np.float64)
    expected = np.tile(np.eye(4), (len(world_from_cam), 1, 1))
    expected[:, :3, :3] = BLENDER_FROM_M3C @ world_from_cam[:, :3, :3] @ GL_FROM_CV
    expected[:, :3, 3] = world_from_cam[:, :3, 3] @ BLENDER_FROM_M3C.T
    np.testing.assert_allclose(matrices[:len(expected)], expected, atol=MM)


def test_glb_and_fbx_in_blender(results, tmp_path):
    source = load_source(results)
    T = source.num_frames
    glb, = export_results(results, "glb", tmp_path / "scene.glb")
    sampled = _sample(glb, tmp_path, source.fps, T - 1)
    assert sampled["fps"] == pytest.approx(10.0)
    # glTF keys at time t land on frame t * fps: processed frame k on Blender frame k.
    _check_joints(sampled, source, lambda arms, t: {k.removeprefix(f"track{t.track_id}_"): v
                                                    for k, v in arms[f"track{t.track_id}"].items()}, 0)
    _check_camera(sampled, source)

    fbx, = export_results(results, "fbx", tmp_path / "scene.fbx")
    sampled = _sample(fbx, tmp_path, source.fps, T - 1)
    _check_joints(sampled, source, lambda arms, t: {k.removeprefix(f"track{t.track_id}_"): v
                                                    for k, v in arms[f"track{t.track_id}"].items()}, 0)
    _check_camera(sampled, source)


def test_bvh_in_blender(results, tmp_path):
    source = load_source(results)
    paths = export_results(results, "bvh", tmp_path)
    for track, path in zip(source.tracks, paths):
        sub = load_source(results, tracks=[track.track_id])
        sub.tracks[0].frames = np.arange(len(track.frames))  # each BVH starts at its track's first frame
        sampled = _sample(path, tmp_path, source.fps, len(track.frames))
        # Blender's BVH importer puts the file's frame k on scene frame k + 1.
        _check_joints(sampled, sub, lambda arms, t: arms[path.stem], 1)
