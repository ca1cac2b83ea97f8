"""Exports read back without Blender: the BVH by m3c.io.bvh, the GLB by pygltflib with forward kinematics done
here from its nodes and animation; both must give results.npz's world joints."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from export_scene import INTRINSICS, WIDTH, HEIGHT, write_results
from m3c.body import default_body_model
from m3c.cli import main
from m3c.export import export_results, load_source
from m3c.io.bvh import read_bvh


@pytest.fixture(scope="module")
def model():
    return default_body_model()


@pytest.fixture(scope="module")
def results(tmp_path_factory, model):
    return write_results(tmp_path_factory.mktemp("export") / "out", model)


def test_bvh_reproduces_world_joints(results, tmp_path):
    source = load_source(results)
    paths = export_results(results, "bvh", tmp_path / "bvh")
    assert [p.name for p in paths] == ["motion_track4.bvh", "motion_track7.bvh"]
    for track, path in zip(source.tracks, paths):
        bvh = read_bvh(path)
        assert bvh.num_frames == len(track.frames) and bvh.fps == pytest.approx(10.0)
        order = [bvh.index(name) for name in source.joint_names]
        joints = bvh.positions()[:, order] / 100.0  # centimetres
        np.testing.assert_allclose(joints, track.world_joints, atol=1e-5)
        # The rest offsets are the track's own shape: bone lengths of the body model at its betas.
        rest = model_rest = track.rest_joints
        assert np.linalg.norm(bvh.joints[bvh.index("left_knee")].offset) == pytest.approx(
            100.0 * np.linalg.norm(rest[4] - model_rest[1]), rel=1e-6)
    metres = read_bvh(export_results(results, "bvh", tmp_path / "one.bvh", tracks=[7], bvh_unit="m")[0])
    np.testing.assert_allclose(metres.positions()[:, [metres.index(n) for n in source.joint_names]],
                               source.tracks[1].world_joints, atol=1e-5)


def _gltf_reader(path):
    import pygltflib as gl

    gltf = gl.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    dtypes = {gl.FLOAT: np.float32, gl.UNSIGNED_BYTE: np.uint8, gl.UNSIGNED_SHORT: np.uint16,
              gl.UNSIGNED_INT: np.uint32}
    sizes = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def read(index):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        n = sizes[acc.type]
        return np.frombuffer(blob, dtypes[acc.componentType], acc.count * n,
                             view.byteOffset + (acc.byteOffset or 0)).reshape(acc.count, n).astype(np.float64)
    return gltf, read


def _animated_world(gltf, read, node_ids, key):
    """World (rotation, translation) of the given nodes at keyframe `key` of the file's one animation."""
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in n.children}
    local = {i: [np.asarray(gltf.nodes[i].translation or [0.0, 0.0, 0.0]),
                 Rotation.from_quat(gltf.nodes[i].rotation or [0, 0, 0, 1]).as_matrix()] for i in node_ids}
    animation = gltf.animations[0]
    for channel in animation.channels:
        if channel.target.node in local:
            value = read(animation.samplers[channel.sampler].output)[key]
            slot = 0 if channel.target.path == "translation" else 1
            local[channel.target.node][slot] = value if slot == 0 else Rotation.from_quat(value).as_matrix()
    world = {}
    for i in node_ids:  # parents come first in a skin's joint list
        t, R = local[i]
        if i in parent and parent[i] in world:
            pR, pt = world[parent[i]]
            world[i] = (pR @ R, pt + pR @ t)
        else:
            world[i] = (R, t)
    return world


def test_glb_reproduces_joints_mesh_and_camera(results, tmp_path, model):
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    source = load_source(results)
    path, = export_results(results, "glb", tmp_path / "scene.glb")
    gltf, read = _gltf_reader(path)
    assert len(gltf.animations) == 1 and len(gltf.skins) == 2
    for skin_index, track in enumerate(source.tracks):
        skin = gltf.skins[skin_index]
        animation = gltf.animations[0]
        root_translation = next(c for c in animation.channels
                                if c.target.node == skin.joints[0] and c.target.path == "translation")
        times = read(animation.samplers[root_translation.sampler].input)
        np.testing.assert_allclose(times[:, 0], track.frames / 10.0, atol=1e-5)
        # Hidden (scale 0, stepped) outside the track: track 7 covers frames 3..9 of 12.
        person = next(i for i, n in enumerate(gltf.nodes) if n.children == [skin.joints[0]])
        presence = [c for c in animation.channels if c.target.node == person and c.target.path == "scale"]
        if track.track_id == 7:
            sampler = animation.samplers[presence[0].sampler]
            assert sampler.interpolation == "STEP"
            np.testing.assert_allclose(read(sampler.input)[:, 0], [0.0, 0.3, 1.0], atol=1e-6)
            np.testing.assert_allclose(read(sampler.output)[:, 0], [0.0, 1.0, 0.0])
        else:
            assert not presence  # track 4 spans the whole video
        inverse_bind = read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        mesh_node = next(n for n in gltf.nodes if n.skin == skin_index)
        prim = gltf.meshes[mesh_node.mesh].primitives[0]
        rest_vertices = read(prim.attributes.POSITION)
        joints, weights = read(prim.attributes.JOINTS_0).astype(int), read(prim.attributes.WEIGHTS_0)
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-5)
        for key in (0, len(track.frames) - 1):
            world = _animated_world(gltf, read, skin.joints, key)
            positions = np.array([world[i][1] for i in skin.joints])
            np.testing.assert_allclose(positions, track.world_joints[key], atol=1e-5)
            # Linear blend skinning of the exported mesh (glTF's formula) against the body model's own mesh,
            # on the vertices the model itself skins with at most 4 joints.
            mats = np.stack([np.block([[world[i][0], world[i][1][:, None]], [np.zeros((1, 3)), 1.0]])
                             for i in skin.joints]) @ inverse_bind
            homog = np.concatenate([rest_vertices, np.ones((len(rest_vertices), 1))], axis=1)
            per_joint = np.einsum("vkij,vj->vki", mats[joints], homog)[..., :3]
            skinned = np.einsum("vk,vki->vi", weights, per_joint)
            truth = model.forward(track.pose[key:key + 1], track.betas, track.transl[key:key + 1]).vertices[0]
            exact = (np.asarray(model.data.weights) > 0).sum(axis=1) <= 4
            np.testing.assert_allclose(skinned[exact], truth[exact], atol=1e-5)
            assert np.abs(skinned - truth).max() < 0.05  # the truncated vertices move a little
    camera_node = next(i for i, n in enumerate(gltf.nodes) if n.camera is not None)
    camera = gltf.cameras[gltf.nodes[camera_node].camera].perspective
    assert camera.yfov == pytest.approx(2 * np.arctan(HEIGHT / 2 / INTRINSICS[1]))
    assert camera.aspectRatio == pytest.approx(WIDTH / HEIGHT)
    world_from_cam = source.arrays["world_from_cam"]
    for key in (0, 5, 11):
        R, t = _animated_world(gltf, read, [camera_node], key)[camera_node]
        np.testing.assert_allclose(t, world_from_cam[key, :3, 3], atol=1e-5)
        # glTF cameras look down -z with y up: the OpenCV forward axis is -z of the node.
        np.testing.assert_allclose(R @ [0, 0, -1], world_from_cam[key, :3, 2], atol=1e-5)
        np.testing.assert_allclose(R @ [0, 1, 0], -world_from_cam[key, :3, 1], atol=1e-5)
    assert any(n.name == "ground" for n in gltf.nodes)


def test_bad_input_gets_a_clear_error_and_no_file(results, tmp_path, capsys):
    assert main(["export", str(tmp_path), "--format", "glb"]) == 2
    assert "holds no M3C results" in capsys.readouterr().err
    out = tmp_path / "x.glb"
    assert main(["export", str(results), "--format", "glb", "--tracks", "5", "--out", str(out)]) == 2
    assert "no track 5" in capsys.readouterr().err and not out.exists()
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["export", str(results), "--format", "bvh", "--out", str(blocker / "bvh")]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert main(["export", str(results), "--format", "bvh", "--out", str(tmp_path / "one.bvh")]) == 2
    assert "2 tracks are selected" in capsys.readouterr().err
    assert main(["export", str(results), "--format", "bvh", "--tracks", "4,x"]) == 2
    assert "comma-separated" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def _cam_joints(source, track):
    """The track's joints in each of its frames' OpenCV cameras, from results.npz."""
    cam_from_world = np.linalg.inv(source.arrays["world_from_cam"][track.frames].astype(np.float64))
    return np.einsum("nij,nkj->nki", cam_from_world[:, :3, :3], track.world_joints) + cam_from_world[:, None, :3, 3]


def test_wham_layout(results, tmp_path, model):
    joblib = pytest.importorskip("joblib", reason="WHAM reads its file with joblib")
    source = load_source(results)
    path, = export_results(results, "wham", tmp_path)
    data = joblib.load(path)
    assert sorted(data) == [4, 7]
    for track in source.tracks:
        entry = data[track.track_id]
        n = len(track.frames)
        assert {k: v.shape for k, v in entry.items()} == {
            "pose": (n, 72), "trans": (n, 3), "pose_world": (n, 72), "trans_world": (n, 3), "betas": (n, 10),
            "frame_ids": (n,)}  # no verts: the open model is not SMPL's 6890-vertex mesh
        np.testing.assert_array_equal(entry["frame_ids"], 2 * track.frames)  # video frames (step 2)
        world = model.joints(entry["pose_world"].reshape(n, 24, 3), entry["betas"][0], entry["trans_world"])
        np.testing.assert_allclose(world, track.world_joints, atol=1e-5)
        cam = model.joints(entry["pose"].reshape(n, 24, 3), entry["betas"][0], entry["trans"])
        np.testing.assert_allclose(cam, _cam_joints(source, track), atol=1e-5)


def test_slahmr_layout(results, tmp_path, model):
    source = load_source(results)
    npz_path, info_path = export_results(results, "slahmr", tmp_path)
    assert npz_path.name == "synthetic_000000_world_results.npz" and npz_path.parent.name == "motion_chunks"
    res = np.load(npz_path)
    T = source.num_frames
    assert {k: res[k].shape for k in res.files} == {
        "trans": (2, T, 3), "root_orient": (2, T, 3), "pose_body": (2, T, 63), "betas": (2, 16),
        "cam_R": (2, T, 3, 3), "cam_t": (2, T, 3), "intrins": (4,), "world_scale": (1, 1), "floor_plane": (1, 3),
        "floor_idcs": (2,)}
    info = json.loads(info_path.read_text())
    world_from_cam0 = source.arrays["world_from_cam"][0].astype(np.float64)
    for b, track in enumerate(source.tracks):
        assert info["tracks"][str(track.track_id)]["index"] == b
        f = track.frames
        pose = np.concatenate([res["root_orient"][b, f][:, None], res["pose_body"][b, f].reshape(-1, 21, 3),
                               np.zeros((len(f), 2, 3))], axis=1)  # SMPL-H body: no hand joints
        joints = model.joints(pose, res["betas"][b, :10], res["trans"][b, f])
        # SLAHMR's world is camera 0's frame; with flat hands the hand joints still sit where M3C's are only
        # when M3C's hand rotations are zero, so compare the 22 body joints.
        back = joints @ world_from_cam0[:3, :3].T + world_from_cam0[:3, 3]
        np.testing.assert_allclose(back[:, :22], track.world_joints[:, :22], atol=1e-5)
        in_cam = np.einsum("nij,nkj->nki", res["cam_R"][b, f], joints) + res["cam_t"][b, f][:, None]
        np.testing.assert_allclose(in_cam[:, :22], _cam_joints(source, track)[:, :22], atol=1e-5)
    # The floor n . x = d (stored as n d) holds the lowest ground point of the world, y = 0, in camera 0.
    plane = res["floor_plane"][0]
    d = np.linalg.norm(plane)
    ground_point_in_cam0 = np.linalg.inv(world_from_cam0) @ [1.3, 0.0, 2.0, 1.0]
    assert plane @ ground_point_in_cam0[:3] / d == pytest.approx(d, abs=1e-5)


def test_gvhmr_layout(results, tmp_path, model):
    torch = pytest.importorskip("torch", reason="GVHMR's layout is a torch file")
    source = load_source(results)
    paths = export_results(results, "gvhmr", tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == ["track4/hmr4d_results.pt",
                                                                    "track7/hmr4d_results.pt"]
    for track, path in zip(source.tracks, paths):
        pred = torch.load(path)
        n = len(track.frames)
        for key, frame in (("smpl_params_global", track.world_joints), ("smpl_params_incam", None)):
            p = {k: v.numpy() for k, v in pred[key].items()}
            assert {k: v.shape for k, v in p.items()} == {"body_pose": (n, 63), "betas": (n, 10),
                                                          "global_orient": (n, 3), "transl": (n, 3)}
            pose = np.concatenate([p["global_orient"][:, None], p["body_pose"].reshape(n, 21, 3),
                                   track.pose[:, 22:]], axis=1)
            joints = model.joints(pose, p["betas"][0], p["transl"])
            expected = track.world_joints if frame is not None else _cam_joints(source, track)
            np.testing.assert_allclose(joints, expected, atol=1e-5)
        np.testing.assert_allclose(pred["K_fullimg"][0].numpy(), [[150, 0, 79.5], [0, 150, 59.5], [0, 0, 1]])


def test_fbx_without_blender_names_the_install(results, tmp_path, monkeypatch, capsys):
    import sys

    monkeypatch.setenv("M3C_BLENDER_PYTHON", sys.executable)  # this Python has no bpy
    out = tmp_path / "scene.fbx"
    assert main(["export", str(results), "--format", "fbx", "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert "cannot import bpy" in err and "pip install bpy==5.0.1" in err and not out.exists()


def test_glb_without_a_ground_has_no_ground_plane(tmp_path, model):
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    folder = write_results(tmp_path / "out", model, num_frames=6, ground=False)
    path, = export_results(folder, "glb")
    assert path == folder / "export" / "scene.glb"
    gltf, _ = _gltf_reader(path)
    assert [n.name for n in gltf.nodes if n.mesh is not None and n.skin is None] == []


def test_results_of_another_body_model_need_its_file(tmp_path):
    """A run with a user's SMPL-sized model (6890 vertices): exports need that file, and WHAM gets its verts."""
    from m3c.body import BodyModel, open_body_model_path
    from m3c.body.synthetic import make_synthetic_model

    data = make_synthetic_model(num_vertices=6890, posedirs_scale=0.0)
    path = tmp_path / "SMPL_LIKE.npz"
    np.savez(path, v_template=data.v_template, shapedirs=data.shapedirs, posedirs=data.posedirs,
             J_regressor=data.J_regressor, weights=data.weights, f=data.faces,
             kintree_table=np.stack([np.where(data.parents < 0, 2 ** 32 - 1, data.parents), np.arange(24)]))
    model = BodyModel.from_file(path)
    folder = write_results(tmp_path / "out", model, num_frames=6)
    with pytest.raises(ValueError, match="SMPL_LIKE.npz.*pass its file"):
        export_results(folder, "wham", tmp_path / "a")
    with pytest.raises(ValueError, match="but the results were made with 'SMPL_LIKE.npz'"):
        export_results(folder, "wham", tmp_path / "b", body_model=open_body_model_path())
    path_out, = export_results(folder, "wham", tmp_path / "c", body_model=path)
    source = load_source(folder, body_model=path)
    with open(path_out, "rb") as fh:
        import pickle

        data_out = pickle.load(fh)
    for track in source.tracks:
        verts = data_out[track.track_id]["verts"]
        world = model.forward(track.pose, track.betas, track.transl).vertices
        cam_from_world = np.linalg.inv(source.arrays["world_from_cam"][track.frames].astype(np.float64))
        expected = np.einsum("nij,nvj->nvi", cam_from_world[:, :3, :3], world) + cam_from_world[:, None, :3, 3]
        np.testing.assert_allclose(verts, expected, atol=1e-4)
