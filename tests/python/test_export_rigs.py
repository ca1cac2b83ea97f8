"""`m3c export --rig`: the motion retargeted onto Mixamo, UE5 mannequin, Unity Humanoid and Rigify skeletons.

The files are read back independently of the retarget: the GLB by pygltflib and the USD by pxr, with forward
kinematics of their rest transforms and animated local rotations done here in numpy; the mapped bones must
land on results.npz's world joints, the finger bones on the fingers posed here by a numpy forward kinematics
of the hand model (checked against results.npz's world_hand_keypoints). In real Blender (bpy, skipped
without it) each rig's GLB and FBX import with the rig's bone names (fingers included) and hierarchy and the
GLB's bone positions (within 1 mm at every frame), and the Mixamo FBX's joints land on the source's within
1 mm."""

from __future__ import annotations

import json

import numpy as np
import pytest
from export_scene import write_results
from m3c.body import default_body_model
from m3c.cli import main
from m3c.export import export_results, load_source
from m3c.export.rigs import RIGS, get_rig
from scipy.spatial.transform import Rotation

CM = 0.01
MM = 1e-3
RIG_NAMES = ("mixamo", "ue5", "unity", "rigify", "smpl")
BLENDER_FROM_M3C = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
# A few bones per rig, named and parented as their published definitions have them (see m3c/export/rigs.py).
EXPECTED = {
    "mixamo": {"mixamorig:Hips": None, "mixamorig:Spine2": "mixamorig:Spine1",
               "mixamorig:LeftShoulder": "mixamorig:Spine2", "mixamorig:LeftArm": "mixamorig:LeftShoulder",
               "mixamorig:LeftForeArm": "mixamorig:LeftArm", "mixamorig:RightUpLeg": "mixamorig:Hips",
               "mixamorig:LeftToeBase": "mixamorig:LeftFoot", "mixamorig:HeadTop_End": "mixamorig:Head"},
    "ue5": {"root": None, "pelvis": "root", "spine_05": "spine_04", "neck_02": "neck_01", "head": "neck_02",
            "clavicle_l": "spine_05", "upperarm_r": "clavicle_r", "thigh_l": "pelvis", "ball_r": "foot_r"},
    "unity": {"Hips": None, "UpperChest": "Chest", "LeftShoulder": "UpperChest",
              "LeftUpperArm": "LeftShoulder", "RightLowerLeg": "RightUpperLeg", "LeftToes": "LeftFoot",
              "Head": "Neck"},
    "rigify": {"DEF-spine": None, "DEF-spine.006": "DEF-spine.005", "DEF-thigh.L": "DEF-spine",
               "DEF-shin.L": "DEF-thigh.L.001", "DEF-upper_arm.R": "DEF-shoulder.R",
               "DEF-shoulder.L": "DEF-spine.003", "DEF-toe.R": "DEF-foot.R"},
    "smpl": {"pelvis": None, "left_knee": "left_hip", "left_shoulder": "left_collar"},
}
# Finger bones, as the rigs' published definitions name and parent them (see m3c/export/rigs.py).
EXPECTED_FINGERS = {
    "mixamo": {"mixamorig:LeftHandThumb1": "mixamorig:LeftHand",
               "mixamorig:LeftHandIndex1": "mixamorig:LeftHand",
               "mixamorig:LeftHandIndex4": "mixamorig:LeftHandIndex3",
               "mixamorig:RightHandPinky2": "mixamorig:RightHandPinky1",
               "mixamorig:RightHandMiddle4": "mixamorig:RightHandMiddle3"},
    "ue5": {"thumb_01_l": "hand_l", "thumb_03_l": "thumb_02_l", "index_metacarpal_l": "hand_l",
            "index_01_l": "index_metacarpal_l", "pinky_metacarpal_r": "hand_r", "ring_03_r": "ring_02_r"},
    "unity": {"LeftThumbProximal": "LeftHand", "LeftIndexIntermediate": "LeftIndexProximal",
              "RightLittleProximal": "RightHand", "RightLittleDistal": "RightLittleIntermediate"},
    "rigify": {"DEF-palm.01.L": "DEF-hand.L", "DEF-f_index.01.L": "DEF-palm.01.L",
               "DEF-thumb.01.L": "DEF-palm.01.L", "DEF-palm.04.R": "DEF-hand.R",
               "DEF-f_pinky.01.R": "DEF-palm.04.R", "DEF-f_pinky.03.R": "DEF-f_pinky.02.R"},
    "smpl": {"left_index1": "left_wrist", "left_index3": "left_index2", "right_thumb1": "right_wrist"},
}
# Finger bones per rig: 3 per finger, Mixamo's tip bones (Thumb4 ..), UE5's and Rigify's 4 metacarpal / palm
# bones per hand.
FINGER_BONES = {"mixamo": 40, "ue5": 38, "unity": 30, "rigify": 38, "smpl": 30}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Results with hand poses (the open model's fingers; the right hand missing on every 4th frame)."""
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    return write_results(tmp_path_factory.mktemp("rigs") / "out", default_body_model(), hands=True)


def _source_joints(source, track) -> np.ndarray:
    """(n, 64, 3) the retarget skeleton's joints in the world: results.npz's 24 body joints, then the 30
    finger joints and the 10 fingertips posed here from the body's world wrist rotations (its local rotations
    composed along SMPL's chain), the hand model's rest offsets and the finger poses (the rest hand where the
    results hold none); where results.npz has world_hand_keypoints they agree to float32 storage."""
    from m3c.body.hands import HAND_PARENTS, MEDIAPIPE_FROM_HAND, TIP_JOINTS

    n = len(track.frames)
    R = Rotation.from_rotvec(track.pose.reshape(-1, 3)).as_matrix().reshape(n, 24, 3, 3)
    world_R = []
    for j, p in enumerate(source.parents):
        world_R.append(R[:, j] if p < 0 else world_R[p] @ R[:, j])
    wrist_rest, joints_rest, tips_rest = track.hands.rest(track.betas)
    hand_R = Rotation.from_rotvec(track.hand_pose.reshape(-1, 3)).as_matrix().reshape(n, 2, 15, 3, 3)
    out = np.zeros((n, 64, 3))
    out[:, :24] = track.world_joints
    for s in (0, 1):
        Rf, xf = [None] * 15, [None] * 15
        for j, p in enumerate(HAND_PARENTS):
            if p < 0:
                pR, px = world_R[20 + s], track.world_joints[:, 20 + s]
                offset = joints_rest[s, j] - wrist_rest[s]
            else:
                pR, px, offset = Rf[p], xf[p], joints_rest[s, j] - joints_rest[s, p]
            xf[j], Rf[j] = px + pR @ offset, pR @ hand_R[:, s, j]
            out[:, 24 + 15 * s + j] = xf[j]
        for f, j in enumerate(TIP_JOINTS):
            out[:, 54 + 5 * s + f] = xf[j] + Rf[j] @ (tips_rest[s, f] - joints_rest[s, j])
    stored = source.arrays["world_hand_keypoints"][track.index, track.frames].astype(np.float64)
    ours = np.concatenate([out[:, None, [20, 21]].transpose(0, 2, 1, 3),
                           out[:, 24:54].reshape(n, 2, 15, 3), out[:, 54:].reshape(n, 2, 5, 3)], axis=2)
    ours = ours[:, :, list(MEDIAPIPE_FROM_HAND)]
    found = np.isfinite(stored).all(axis=(2, 3))
    assert found.any() and not found.all()
    np.testing.assert_allclose(ours[found], stored[found], atol=1e-5)
    return out


def _read_glb(path):
    import pygltflib as gl

    gltf = gl.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    sizes = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def read(index):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        dtype = {gl.FLOAT: np.float32, gl.UNSIGNED_BYTE: np.uint8, gl.UNSIGNED_INT: np.uint32,
                 gl.UNSIGNED_SHORT: np.uint16}[acc.componentType]
        n = sizes[acc.type]
        return np.frombuffer(blob, dtype, acc.count * n, view.byteOffset + (acc.byteOffset or 0)).reshape(
            acc.count, n).astype(np.float64)
    return gltf, read


def _glb_world(path):
    """{bone name: (K, 3) world head per key} and the key times, by forward kinematics of the file's nodes."""
    gltf, read = _read_glb(path)
    skin = gltf.skins[0]
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in n.children}
    animation = gltf.animations[0]
    times = read(animation.samplers[0].input)[:, 0]
    K = len(times)
    T = {i: np.tile(np.asarray(gltf.nodes[i].translation or [0.0] * 3, float), (K, 1)) for i in skin.joints}
    R = {i: np.tile(Rotation.from_quat(gltf.nodes[i].rotation or [0, 0, 0, 1]).as_matrix(), (K, 1, 1))
         for i in skin.joints}
    for ch in animation.channels:
        value = read(animation.samplers[ch.sampler].output)
        if ch.target.path == "translation":
            T[ch.target.node] = value
        elif ch.target.path == "rotation":
            R[ch.target.node] = Rotation.from_quat(value).as_matrix()
    world = {}
    for i in skin.joints:   # parents first
        if i in parent and parent[i] in world:
            pR, pt = world[parent[i]]
            world[i] = (pR @ R[i], pt + np.einsum("kij,kj->ki", pR, T[i]))
        else:
            world[i] = (R[i], T[i])
    names = {i: gltf.nodes[i].name for i in skin.joints}
    parents = {names[i]: names.get(parent.get(i)) for i in skin.joints}
    return {names[i]: world[i][1] for i in skin.joints}, times, parents, gltf, read


@pytest.mark.parametrize("rig", RIG_NAMES)
def test_glb_bones_land_on_the_world_joints(results, tmp_path, rig):
    source = load_source(results)
    paths = export_results(results, "glb", tmp_path, rig=rig, root_motion="performer")
    if rig == "smpl":  # --rig smpl alone is today's scene export
        assert [p.name for p in paths] == ["scene.glb"]
        paths = export_results(results, "glb", tmp_path, rig=rig, smoothing="off", reference_pose="tpose")
        assert [p.name for p in paths] == ["smpl_track4.glb", "smpl_track7.glb"]
    else:
        assert [p.name for p in paths] == [f"{rig}_track4.glb", f"{rig}_track7.glb"]
    definition = get_rig(rig)
    for track, path in zip(source.tracks, paths):
        world, times, parents, _, _ = _glb_world(path)
        assert set(world) == set(definition.names) and len(world) == len(definition.names)
        for name, parent in {**EXPECTED[rig], **EXPECTED_FINGERS[rig]}.items():
            assert parents[name] == parent, name
        assert len(definition.finger_bones) == FINGER_BONES[rig]
        first = 1 if rig == "smpl" else 0  # the reference pose's extra frame
        assert len(times) == len(track.frames) + first
        np.testing.assert_allclose(times, np.arange(len(times)) / source.fps, atol=1e-6)
        truth = _source_joints(source, track)
        mapped = definition.mapped()
        assert sum(joint >= 24 for joint in mapped.values()) == {"mixamo": 40, "smpl": 30}.get(rig, 30)
        for name, joint in mapped.items():
            error = np.linalg.norm(world[name][first:] - truth[:, joint], axis=-1).max()
            assert error < CM, (name, error)
            assert error < 1e-4, (name, error)   # float32 storage: far below the centimetre asked


def test_hands_never_seen_give_rest_fingers(tmp_path, monkeypatch):
    """The hands node ran but saw no hand (the bundled walker): every rig still has its fingers, at rest."""
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    import export_scene

    seen = export_scene.make_hands

    def unseen(tracks, seed):
        hands = seen(tracks, seed)
        for track in hands["tracks"]:
            for key in ("hand_pose", "wrist_correction", "keypoints"):
                track[key][:] = np.nan
        return hands
    monkeypatch.setattr(export_scene, "make_hands", unseen)
    blind = export_scene.write_results(tmp_path / "out", default_body_model(), hands=True)
    source = load_source(blind, tracks=[4])
    track = source.tracks[0]
    assert not np.isfinite(source.arrays["left_hand_pose"]).any()
    np.testing.assert_array_equal(track.hand_pose, 0.0)
    path, = export_results(blind, "glb", tmp_path / "ue5", tracks=[4], rig="ue5")
    world = _glb_world(path)[0]
    assert set(get_rig("ue5").finger_bones) <= set(world)
    from m3c.body.hands import pose_hands
    from scipy.spatial.transform import Rotation as R_

    n = len(track.frames)
    local = R_.from_rotvec(track.pose.reshape(-1, 3)).as_matrix().reshape(n, 24, 3, 3)
    chain = []
    for j, p in enumerate(source.parents):
        chain.append(local[:, j] if p < 0 else chain[p] @ local[:, j])
    rest = pose_hands(track.hands, track.betas, np.stack([chain[20], chain[21]], 1),
                      track.world_joints[:, [20, 21]], np.zeros((n, 2, 15, 3)))
    for name, joint in get_rig("ue5").mapped().items():
        if joint >= 24:
            s, k = divmod(joint - 24, 15)
            assert np.linalg.norm(world[name] - rest.joints[:, s, k], axis=-1).max() < 1e-4, name


def test_rigs_without_hand_poses_have_no_finger_bones(tmp_path):
    """Results without hand poses (an SMPL body, --no-hands): the rigs' body bones only, on the world
    joints."""
    pytest.importorskip("pygltflib", reason="GLB export needs pygltflib (pip install m3c[export])")
    plain = write_results(tmp_path / "out", default_body_model())
    source = load_source(plain, tracks=[4])
    assert source.tracks[0].hand_pose is None
    for rig in ("mixamo", "rigify"):
        path, = export_results(plain, "glb", tmp_path / rig, tracks=[4], rig=rig)
        world, _, parents, _, _ = _glb_world(path)
        body = get_rig(rig).body_only()
        assert set(world) == set(body.names) and not set(world) & set(get_rig(rig).finger_bones)
        for name, joint in body.mapped().items():
            assert np.linalg.norm(world[name] - source.tracks[0].world_joints[:, joint], axis=-1).max() < 1e-4


@pytest.mark.parametrize("rig", ("mixamo", "ue5", "rigify"))
def test_glb_skinned_mesh_is_the_body_models(results, tmp_path, rig):
    """glTF's skinning of the exported mesh (rig rest pose, rig bones) against the body model's own posed
    mesh, on the vertices the model skins with at most 4 joints and none of its hand joints (the rigs' wrists
    carry the hands). Not exact: the mesh is bound anew in the rig's rest pose, and where a vertex follows
    joints whose limbs that pose straightened differently (shoulders, hips), skinning from the new rest blends
    a little differently: measured on these random poses, up to 3 mm from the T poses, 1.4 cm from UE5's A
    pose, the median vertex exact."""
    model = default_body_model()
    source = load_source(results, tracks=[4])
    track = source.tracks[0]
    path, = export_results(results, "glb", tmp_path, tracks=[4], rig=rig)
    world_heads, _, _, gltf, read = _glb_world(path)
    skin = gltf.skins[0]
    inverse_bind = read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    body = next(n for n in gltf.nodes if n.mesh is not None)
    prim = gltf.meshes[body.mesh].primitives[0]
    rest = read(prim.attributes.POSITION)
    joints, weights = read(prim.attributes.JOINTS_0).astype(int), read(prim.attributes.WEIGHTS_0)
    smpl_weights = np.asarray(model.data.weights)
    exact = (smpl_weights[:, 22:].sum(axis=1) == 0) & ((smpl_weights > 0).sum(axis=1) <= 4)
    assert exact.mean() > 0.5
    # The joints' world transforms at key k, by forward kinematics of the file's nodes and animation.
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in n.children}
    animation = gltf.animations[0]
    for k in (0, len(track.frames) - 1):
        local = {i: [np.asarray(gltf.nodes[i].translation, float),
                     Rotation.from_quat(gltf.nodes[i].rotation).as_matrix()] for i in skin.joints}
        for ch in animation.channels:
            value = read(animation.samplers[ch.sampler].output)[k]
            if ch.target.path == "translation":
                local[ch.target.node][0] = value
            else:
                local[ch.target.node][1] = Rotation.from_quat(value).as_matrix()
        world = {}
        for i in skin.joints:
            t, R = local[i]
            if i in parent and parent[i] in world:
                pm = world[parent[i]]
                world[i] = pm @ np.block([[R, t[:, None]], [np.zeros((1, 3)), 1.0]])
            else:
                world[i] = np.block([[R, t[:, None]], [np.zeros((1, 3)), 1.0]])
        mats = np.stack([world[i] for i in skin.joints]) @ inverse_bind
        homog = np.concatenate([rest, np.ones((len(rest), 1))], axis=1)
        skinned = np.einsum("vk,vki->vi", weights, np.einsum("vkij,vj->vki", mats[joints], homog)[..., :3])
        pose = track.pose[k:k + 1]
        truth = model.forward(pose, track.betas, track.transl[k:k + 1]).vertices[0]
        np.testing.assert_allclose(skinned[exact], truth[exact], atol=(2 * CM if rig == "ue5" else 5 * MM))
        assert np.median(np.abs(skinned[exact] - truth[exact])) < 1e-5


def test_rest_pose_bone_lengths_and_axes(results, tmp_path):
    """Rest poses: Mixamo's T (arms along +-x), UE5's A (arms 45 degrees down), legs vertical; the rest bones
    are the performer's (the body model's joints at the track's betas)."""
    source = load_source(results)
    track = source.tracks[0]
    J = track.rest_joints
    for rig, arm, up_leg, lower_arm in (("mixamo", "mixamorig:LeftArm", "mixamorig:LeftUpLeg",
                                         "mixamorig:LeftForeArm"),
                                        ("ue5", "upperarm_l", "thigh_l", "lowerarm_l")):
        path = export_results(results, "glb", tmp_path / rig, tracks=[4], rig=rig, reference_pose="none")[0]
        gltf, read = _read_glb(path)
        skin = gltf.skins[0]
        inverse_bind = read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        rest = {gltf.nodes[i].name: np.linalg.inv(m) for i, m in zip(skin.joints, inverse_bind)}
        head = {k: v[:3, 3] for k, v in rest.items()}
        upper_arm = head[lower_arm] - head[arm]
        assert np.linalg.norm(upper_arm) == pytest.approx(np.linalg.norm(J[18] - J[16]), abs=1e-5)
        drop = 0.0 if rig == "mixamo" else 45.0
        np.testing.assert_allclose(upper_arm / np.linalg.norm(upper_arm),
                                   [np.cos(np.radians(drop)), -np.sin(np.radians(drop)), 0.0], atol=1e-5)
        knee = [n for n, p in _glb_world(path)[2].items() if p == up_leg][0]
        thigh = head[knee] - head[up_leg]
        assert np.linalg.norm(thigh) == pytest.approx(np.linalg.norm(J[4] - J[1]), abs=1e-5)
        np.testing.assert_allclose(thigh / np.linalg.norm(thigh), [0.0, -1.0, 0.0], atol=1e-5)
        # Bone axes: Mixamo's +Y along the bone (Blender's convention), UE5's +X (Unreal's); a finger bone's
        # toward its next joint, the hand's toward its middle finger.
        axis = 1 if rig == "mixamo" else 0
        for bone, child in ((arm, lower_arm),
                            *((("mixamorig:LeftHandIndex1", "mixamorig:LeftHandIndex2"),
                               ("mixamorig:RightHandThumb2", "mixamorig:RightHandThumb3"),
                               ("mixamorig:LeftHand", "mixamorig:LeftHandMiddle1")) if rig == "mixamo" else
                              (("index_01_l", "index_02_l"), ("thumb_02_r", "thumb_03_r"),
                               ("hand_l", "middle_metacarpal_l"), ("middle_metacarpal_l", "middle_01_l")))):
            direction = head[child] - head[bone]
            np.testing.assert_allclose(rest[bone][:3, axis], direction / np.linalg.norm(direction), atol=1e-5,
                                       err_msg=bone)
        # The mesh stands on y = 0.
        body = next(n for n in gltf.nodes if n.mesh is not None)
        assert read(gltf.meshes[body.mesh].primitives[0].attributes.POSITION)[:, 1].min() == pytest.approx(
            0.0, abs=1e-5)


def test_reference_pose_frame(results, tmp_path):
    source = load_source(results)
    path = export_results(results, "glb", tmp_path, tracks=[7], rig="ue5", reference_pose="tpose")[0]
    world, times, *_ = _glb_world(path)
    assert len(times) == len(source.tracks[1].frames) + 1
    arm = world["lowerarm_r"][0] - world["upperarm_r"][0]
    np.testing.assert_allclose(arm / np.linalg.norm(arm), [-1.0, 0.0, 0.0], atol=1e-5)  # T pose, facing +z
    shin = world["foot_l"][0] - world["calf_l"][0]
    np.testing.assert_allclose(shin / np.linalg.norm(shin), [0.0, -1.0, 0.0], atol=1e-5)


def test_in_place_root_motion(results, tmp_path):
    source = load_source(results)
    for track, path in zip(source.tracks, export_results(results, "glb", tmp_path, rig="mixamo",
                                                         root_motion="in-place")):
        world = _glb_world(path)[0]
        hips = world["mixamorig:Hips"]
        np.testing.assert_allclose(hips[:, [0, 2]], 0.0, atol=1e-6)            # no horizontal travel
        np.testing.assert_allclose(hips[:, 1], track.world_joints[:, 0, 1], atol=1e-5)   # height kept
        # Heading kept: the hips' left-right axis turns as the source's does.
        ours = world["mixamorig:LeftUpLeg"] - world["mixamorig:RightUpLeg"]
        theirs = track.world_joints[:, 1] - track.world_joints[:, 2]
        np.testing.assert_allclose(ours, theirs, atol=1e-5)


def test_foot_lock_holds_planted_feet_under_smoothing(results, tmp_path):
    source = load_source(results)
    contacts = source.arrays["contacts"]
    paths = export_results(results, "glb", tmp_path, rig="unity", smoothing="strong")
    for track, path in zip(source.tracks, paths):
        world = _glb_world(path)[0]
        c = contacts[track.index, track.frames]
        for side, (ankle, joint) in enumerate((("LeftFoot", 7), ("RightFoot", 8))):
            planted = np.maximum(c[:, side], c[:, side + 2]) > 0.5
            assert planted.any()
            error = np.linalg.norm(world[ankle] - track.world_joints[:, joint], axis=-1)[planted]
            assert error.max() < CM, error.max()


def test_foot_lock_against_the_body_model_on_jittery_motion():
    """Jittered poses, strongly smoothed: the smoothing moves the feet by centimetres, the lock holds the
    planted ones on the body model's own posed ankles and toes (m3c's C++ forward kinematics, not the
    retarget's)."""
    model = default_body_model()
    rng = np.random.default_rng(3)
    n, fps = 40, 30.0
    t = np.arange(n) / fps
    betas = rng.normal(scale=0.5, size=10)
    swing = np.sin(3 * t)[:, None, None]
    pose = 0.2 * rng.normal(size=(1, 24, 3)) + 0.3 * swing * rng.normal(size=(1, 24, 3))
    pose = pose + 0.08 * rng.normal(size=(n, 24, 3))    # jitter
    pose[:, 0] = Rotation.from_euler("y", 0.4 * t[:, None]).as_rotvec()
    transl = np.stack([0.5 * t, 0.9 + 0.03 * rng.normal(size=n), 0.2 * t], axis=1)
    joints = model.joints(pose, np.tile(betas, (n, 1)), transl)
    rest = model.joints(np.zeros((1, 24, 3)), betas)[0]
    mesh = model.forward(np.zeros((1, 24, 3)), betas).vertices[0]
    contacts = np.zeros((n, 4))
    contacts[5:20, 0] = contacts[22:35, 1] = contacts[8:14, 2] = 0.9
    from m3c.export.rigs import retarget

    planted = {0: np.maximum(contacts[:, 0], contacts[:, 2]) > 0.5, 1: contacts[:, 1] > 0.5}
    errors = {}
    for lock in (True, False):
        motion = retarget("mixamo", rest, pose, rest[0] + transl, fps, mesh, np.asarray(model.data.weights),
                          contacts, smoothing="strong", foot_lock=lock)
        worst = 0.0
        for side, (ankle, toe) in enumerate((("mixamorig:LeftFoot", "mixamorig:LeftToeBase"),
                                             ("mixamorig:RightFoot", "mixamorig:RightToeBase"))):
            for name, joint in ((ankle, 7 + side), (toe, 10 + side)):
                head = motion.world_positions[:, motion.names.index(name)]
                worst = max(worst, np.linalg.norm(head - joints[:, joint], axis=-1)[planted[side]].max())
        errors[lock] = worst
    assert errors[True] < CM and errors[False] > 2 * CM, errors


def test_usd_skeleton_lands_on_the_world_joints(results, tmp_path):
    pytest.importorskip("pxr", reason="USD export needs usd-core (pip install usd-core)")
    from pxr import Usd, UsdSkel

    source = load_source(results)
    paths = export_results(results, "usd", tmp_path, rig="mixamo")
    assert [p.name for p in paths] == ["mixamo_track4.usda", "mixamo_track7.usda"]
    definition = get_rig("mixamo")
    for track, path in zip(source.tracks, paths):
        stage = Usd.Stage.Open(str(path))
        assert stage.GetTimeCodesPerSecond() == pytest.approx(source.fps)
        skel = next(UsdSkel.Skeleton(p) for p in stage.Traverse() if p.IsA(UsdSkel.Skeleton))
        anim = next(UsdSkel.Animation(p) for p in stage.Traverse() if p.IsA(UsdSkel.Animation))
        names = list(skel.GetJointNamesAttr().Get())
        paths_ = list(skel.GetJointsAttr().Get())
        assert names == definition.names
        parent = [paths_.index(p.rsplit("/", 1)[0]) if "/" in p else -1 for p in paths_]
        truth = _source_joints(source, track)
        for k in (0, len(track.frames) // 2, len(track.frames) - 1):
            t = np.array(anim.GetTranslationsAttr().Get(k), float)
            q = np.array([[r.GetReal(), *r.GetImaginary()] for r in anim.GetRotationsAttr().Get(k)])
            R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
            Rw, tw = [None] * len(names), [None] * len(names)
            for i, p in enumerate(parent):
                Rw[i], tw[i] = (R[i], t[i]) if p < 0 else (Rw[p] @ R[i], tw[p] + Rw[p] @ t[i])
            # USD's own skeleton evaluation agrees (row-vector matrices: the translation is the last row).
            skel_space = UsdSkel.Cache().GetSkelQuery(skel).ComputeJointSkelTransforms(Usd.TimeCode(k))
            for name, joint in definition.mapped().items():   # the fingers and tips included
                assert np.linalg.norm(tw[names.index(name)] - truth[k, joint]) < 1e-4, name
                usd = np.array(skel_space[names.index(name)])[3, :3]
                assert np.linalg.norm(usd - truth[k, joint]) < 1e-4, name


def test_cli_rig_options(results, tmp_path, capsys):
    out = tmp_path / "mixamo"
    assert main(["export", str(results), "--format", "glb", "--rig", "mixamo", "--root-motion", "in-place",
                 "--smoothing", "standard", "--reference-pose", "apose", "--tracks", "4",
                 "--out", str(out)]) == 0
    assert capsys.readouterr().out.split() == [str(out / "mixamo_track4.glb")]
    bvh = ["export", str(results), "--format", "bvh", "--rig", "ue5", "--out", str(tmp_path / "b")]
    assert main(bvh) == 2
    assert "not bvh" in capsys.readouterr().err
    assert set(RIGS) == set(RIG_NAMES)


# --- real Blender -------------------------------------------------------------------------------------------

def _blender_missing() -> str:
    from m3c.export.blender import BlenderUnavailable, blender_python

    try:
        blender_python()
        return ""
    except BlenderUnavailable as err:
        return str(err)


@pytest.fixture(scope="module")
def blender():
    missing = _blender_missing()
    if missing:
        pytest.skip(f"Blender (bpy) absent: {missing}")
    from m3c.export.blender import run_blender
    return run_blender


def _sample(run_blender, path, tmp_path, fps, last):
    out = tmp_path / f"{path.name}.json"
    run_blender("sample", path, fps, 0, last, out)
    return json.loads(out.read_text())


@pytest.mark.parametrize("rig", ("mixamo", "ue5", "unity", "rigify"))
def test_rig_glb_and_fbx_in_blender(results, tmp_path, blender, rig):
    source = load_source(results, tracks=[7])
    track = source.tracks[0]
    definition = get_rig(rig)
    expected_parents = dict(zip(definition.names, [definition.names[p] if p >= 0 else None
                                                   for p in definition.parents]))
    glb, = export_results(results, "glb", tmp_path / "glb", tracks=[7], rig=rig)
    fbx, = export_results(results, "fbx", tmp_path / "fbx", tracks=[7], rig=rig)
    last = len(track.frames) - 1
    world = _glb_world(glb)[0]
    truth = _source_joints(source, track) @ BLENDER_FROM_M3C.T
    assert len(definition.finger_bones) == FINGER_BONES[rig]
    for path in (glb, fbx):
        sampled = _sample(blender, path, tmp_path, source.fps, last)
        (armature, parents), = sampled["parents"].items()
        assert parents == expected_parents, path.name   # the finger bones included
        heads = sampled["armatures"][armature]   # every frame, every bone, within 1 mm of the GLB's
        for name in definition.names:
            np.testing.assert_allclose(np.array(heads[name]), world[name] @ BLENDER_FROM_M3C.T, atol=MM,
                                       err_msg=f"{path.name} {name}")
        if rig == "mixamo":   # re-imported, the joints (fingers included) are the source's within 1 mm
            for name, joint in definition.mapped().items():
                error = np.linalg.norm(np.array(heads[name]) - truth[:, joint], axis=-1).max()
                assert error < MM, (path.name, name, error)


def test_usd_without_usd_core_says_how_to_install(results, tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pxr", None)   # import pxr now raises ImportError
    out = tmp_path / "usd"
    code = main(["export", str(results), "--format", "usd", "--rig", "ue5", "--out", str(out)])
    assert code == 3 and "pip install usd-core" in capsys.readouterr().err
    assert not out.exists()
