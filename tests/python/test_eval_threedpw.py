"""3DPW reader on a small file written here in the dataset's layout, and the world/camera body transform."""

import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.eval.datasets import OPENPOSE18_TO_COCO17, list_sequences, read_sequence
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.eval.tracks import body_eval_track


def random_cameras(rng, n):
    cam_from_world = np.tile(np.eye(4), (n, 1, 1))
    cam_from_world[:, :3, :3] = Rotation.random(n, random_state=11).as_matrix()
    cam_from_world[:, :3, 3] = rng.normal(size=(n, 3)) + [0, 0, 5]
    return cam_from_world


def write_3dpw(path, model, rng, n=6, people=2, gender_key="genders"):
    """A sequence file as 3DPW writes it: lists per actor, (N, 3, 18) 2D poses, 72-d poses and joints."""
    poses, trans, joints, poses2d, valid, betas = [], [], [], [], [], []
    for k in range(people):
        pose = 0.3 * rng.normal(size=(n, 24, 3))
        b = rng.normal(size=10)
        t = rng.normal(size=(n, 3))
        poses.append(pose.reshape(n, 72))
        trans.append(t)
        joints.append(model.joints(pose, b, t).reshape(n, 72))
        kp = np.zeros((n, 3, 18))
        kp[:, 0, :] = np.arange(18) + 100 * k  # x encodes the OpenPose index
        kp[:, 2, :] = 0.5
        poses2d.append(kp)
        v = np.ones(n, dtype=bool)
        v[k] = False
        valid.append(v)
        betas.append(np.concatenate([b, np.zeros(290)]))  # some files carry more than 10
    data = {"sequence": "courtyard_test_00", "poses": poses, "trans": trans, "jointPositions": joints,
            "poses2d": poses2d, "campose_valid": valid, gender_key: ["m", "f"][:people], "betas": betas,
            "cam_poses": random_cameras(rng, n), "cam_intrinsics": np.array([[1961.0, 0, 540], [0, 1969.0, 960],
                                                                            [0, 0, 1]]),
            "img_frame_ids": np.arange(n), "poses_60Hz": poses, "texture_maps": ["x"] * people}
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        pickle.dump(data, fh, protocol=2)
    return data


def test_read_sequence_fields_and_shapes(tmp_path, synthetic_body_model, rng):
    path = tmp_path / "3DPW" / "sequenceFiles" / "test" / "courtyard_test_00.pkl"
    data = write_3dpw(path, synthetic_body_model, rng)
    seq = read_sequence(path)
    assert seq.name == "courtyard_test_00" and seq.split == "test" and seq.num_frames == 6
    np.testing.assert_allclose(seq.intrinsics, [1961.0, 1969.0, 540.0, 960.0])
    np.testing.assert_allclose(seq.world_from_cam @ data["cam_poses"], np.tile(np.eye(4), (6, 1, 1)), atol=1e-12)
    assert [p.gender for p in seq.people] == ["male", "female"]
    for k, person in enumerate(seq.people):
        assert person.body_pose.shape == (6, 23, 3) and person.joints.shape == (6, 24, 3)
        np.testing.assert_allclose(person.root_orient, data["poses"][k][:, :3])
        np.testing.assert_allclose(person.betas, data["betas"][k][:10])
        # COCO-17 row j holds OpenPose row OPENPOSE18_TO_COCO17[j] (x was written as the OpenPose index).
        np.testing.assert_allclose(person.keypoints[0, :, 0], np.array(OPENPOSE18_TO_COCO17) + 100 * k)
        assert person.keypoints.shape == (6, 17, 3)
        assert not person.valid[k] and person.valid.sum() == 5
    assert list_sequences(tmp_path / "3DPW", "test") == [path]


def test_read_sequence_accepts_the_readme_gender_key(tmp_path, synthetic_body_model, rng):
    path = tmp_path / "seq.pkl"
    write_3dpw(path, synthetic_body_model, rng, people=1, gender_key="gender")
    assert read_sequence(path).people[0].gender == "male"


def test_read_sequence_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="3DPW"):
        read_sequence(tmp_path / "missing.pkl")
    path = tmp_path / "bad.pkl"
    with open(path, "wb") as fh:
        pickle.dump({"poses": []}, fh)
    with pytest.raises(ValueError, match="'trans' is missing"):
        read_sequence(path)
    with pytest.raises(ValueError, match="split"):
        list_sequences(tmp_path, "val")


def test_transform_smpl_with_per_frame_cameras_matches_moving_the_joints(synthetic_body_model, rng):
    model = synthetic_body_model
    n = 5
    pose = 0.4 * rng.normal(size=(n, 24, 3))
    betas = rng.normal(size=10)
    transl = rng.normal(size=(n, 3))
    T = random_cameras(rng, n)
    root, tr = transform_smpl(T, pose[:, 0], transl, rest_root_joint(model, betas))
    moved = model.joints(np.concatenate([root[:, None], pose[:, 1:]], axis=1), betas, tr)
    world = model.joints(pose, betas, transl)
    expect = np.einsum("nij,nkj->nki", T[:, :3, :3], world) + T[:, None, :3, 3]
    np.testing.assert_allclose(moved, expect, atol=1e-10)
    # Per-frame shapes: one rest root joint per frame.
    betas_n = rng.normal(size=(n, 10))
    root, tr = transform_smpl(T, pose[:, 0], transl, rest_root_joint(model, betas_n))
    moved = model.joints(np.concatenate([root[:, None], pose[:, 1:]], axis=1), betas_n, tr)
    world = model.joints(pose, betas_n, transl)
    expect = np.einsum("nij,nkj->nki", T[:, :3, :3], world) + T[:, None, :3, 3]
    np.testing.assert_allclose(moved, expect, atol=1e-10)


def test_body_eval_track_camera_and_world_agree(synthetic_body_model, rng):
    model = synthetic_body_model
    n = 4
    pose = 0.3 * rng.normal(size=(n, 24, 3))
    betas = rng.normal(size=10)
    transl = rng.normal(size=(n, 3))
    world_from_cam = np.linalg.inv(random_cameras(rng, n))
    track = body_eval_track(model, np.arange(10, 10 + n), pose[:, 0], pose[:, 1:], betas, transl, world_from_cam)
    back = np.einsum("nij,nkj->nki", world_from_cam[:, :3, :3], track.joints_cam) + world_from_cam[:, None, :3, 3]
    np.testing.assert_allclose(back, track.joints_world, atol=1e-10)
    np.testing.assert_allclose(track.joints_world, model.joints(pose, betas, transl), atol=1e-10)
    assert track.vertices_cam.shape == (n, model.num_vertices, 3)
    assert track.feet_world.shape == (n, 4, 3)  # toes and heels
    part = track.take(slice(1, 3))
    np.testing.assert_array_equal(part.frames, [11, 12])
