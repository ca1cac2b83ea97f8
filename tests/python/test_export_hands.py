"""Exports carry the fingers: results with hand poses (the hands node's layout) give BVH and GLB files whose
30 finger joints, read back and posed by their own hierarchy, land on the hands m3c.body.hands poses, and
whose GLB hand vertices skin like m3c.body.hands.skin_hands."""

from __future__ import annotations

import numpy as np
import pytest
from export_scene import write_results
from m3c.body import default_body_model
from m3c.body.hands import (
    HAND_JOINT_NAMES,
    MEDIAPIPE_FROM_HAND,
    SIDES,
    load_hand_model,
    skin_hands,
    wrist_frames,
)
from m3c.export import export_results, load_source
from m3c.io.bvh import read_bvh
from m3c.io.results import load_results
from test_export import _animated_world, _gltf_reader

FINGER_ROWS = [MEDIAPIPE_FROM_HAND.index(1 + j) for j in range(15)]  # world_hand_keypoints rows of the joints
NAMES = [f"{side}_{name}" for side in SIDES for name in HAND_JOINT_NAMES]


@pytest.fixture(scope="module")
def model():
    return default_body_model()


@pytest.fixture(scope="module")
def results(tmp_path_factory, model):
    return write_results(tmp_path_factory.mktemp("export_hands") / "out", model, hands=True)


def finger_truth(arrays, track) -> np.ndarray:
    """(n, 30, 3) the results' posed finger joints (NaN where no hand)."""
    points = arrays["world_hand_keypoints"][track.index, track.frames].astype(np.float64)
    return np.concatenate([points[:, 0, FINGER_ROWS], points[:, 1, FINGER_ROWS]], axis=1)


def test_results_hold_hands_and_keep_the_optimizers_wrists(results):
    _, arrays = load_results(results)
    assert arrays["left_hand_pose"].shape[2:] == (15, 3)
    assert arrays["hand_keypoints_2d"].shape[2:] == (2, 21, 3)
    valid = arrays["valid"]
    assert np.isfinite(arrays["left_hand_pose"][valid]).all()
    right = np.isfinite(arrays["right_hand_pose"][valid]).all(axis=(1, 2))
    assert 0 < right.sum() < valid.sum()  # a few frames without a right hand
    # The body keeps the optimizer's pose, wrists included (the hand fit's wrist refinement stays inside the
    # finger fit: written into body_pose it raised the benchmark's jitter); the scene's lift is the optimizer's
    # input plus 0.02.
    before = arrays["lift_body_pose"][valid] - 0.02
    np.testing.assert_allclose(arrays["body_pose"][valid], before, atol=1e-5)


def test_bvh_carries_the_fingers(results, tmp_path):
    source = load_source(results)
    _, arrays = load_results(results)
    for track, path in zip(source.tracks, export_results(results, "bvh", tmp_path / "bvh")):
        bvh = read_bvh(path)
        positions = bvh.positions() / 100.0
        body = positions[:, [bvh.index(n) for n in source.joint_names]]
        np.testing.assert_allclose(body, track.world_joints, atol=1e-5)
        fingers = positions[:, [bvh.index(n) for n in NAMES]]
        truth = finger_truth(arrays, track)
        found = np.isfinite(truth).all(axis=2)
        assert found.mean() > 0.8
        np.testing.assert_allclose(fingers[found], truth[found], atol=1e-5)


def test_glb_carries_the_fingers_and_skins_the_hands(results, tmp_path, model):
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    source = load_source(results)
    _, arrays = load_results(results)
    hand = load_hand_model()
    path, = export_results(results, "glb", tmp_path / "scene.glb")
    gltf, read = _gltf_reader(path)
    for skin_index, track in enumerate(source.tracks):
        skin = gltf.skins[skin_index]
        assert len(skin.joints) == 54
        assert [gltf.nodes[i].name.split("_", 1)[1] for i in skin.joints[24:]] == NAMES
        inverse_bind = read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        mesh_node = next(n for n in gltf.nodes if n.skin == skin_index)
        prim = gltf.meshes[mesh_node.mesh].primitives[0]
        rest_vertices = read(prim.attributes.POSITION)
        joints, weights = read(prim.attributes.JOINTS_0).astype(int), read(prim.attributes.WEIGHTS_0)
        truth = finger_truth(arrays, track)
        for key in (0, 1, len(track.frames) - 1):
            world = _animated_world(gltf, read, skin.joints, key)
            positions = np.array([world[i][1] for i in skin.joints])
            np.testing.assert_allclose(positions[:24], track.world_joints[key], atol=1e-5)
            found = np.isfinite(truth[key]).all(axis=1)
            np.testing.assert_allclose(positions[24:][found], truth[key][found], atol=1e-5)
            mats = np.stack([np.block([[world[i][0], world[i][1][:, None]], [np.zeros((1, 3)), 1.0]])
                             for i in skin.joints]) @ inverse_bind
            homog = np.concatenate([rest_vertices, np.ones((len(rest_vertices), 1))], axis=1)
            per_joint = np.einsum("vkij,vj->vki", mats[joints], homog)[..., :3]
            skinned = np.einsum("vk,vki->vi", weights, per_joint)
            pose, betas, transl = track.pose[key:key + 1].copy(), track.betas, track.transl[key:key + 1]
            pose[:, 22:24] = 0.0  # the fingers replace the hand joints (M3C keeps them at rest)
            rotation, position = wrist_frames(model, pose, betas, transl)
            body = model.forward(pose, betas, transl).vertices
            rest = model.data.v_template + model.data.shapedirs @ betas
            expected = skin_hands(hand, betas, rest, body, rotation, position,
                                  track.hand_pose[key:key + 1])[0]
            for s, side in enumerate(SIDES):
                ids = hand.vertex_ids[side]
                body_weights = np.asarray(model.data.weights)[ids].copy()
                body_weights[:, 22 + s] = 0.0  # the fingers replace the hand joint
                combined = np.concatenate([body_weights, hand.weights[side]], axis=1)
                exact = ids[(combined > 0).sum(axis=1) <= 4]  # glTF keeps 4 influences
                assert len(exact) > 100
                np.testing.assert_allclose(skinned[exact], expected[exact], atol=1e-5)
