"""3DPW evaluation of prediction files, on a small dataset written here in 3DPW's layout (synthetic body
model)."""

import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body.joint_names import H36M_TO_J14, J14_PELVIS
from m3c.eval import metrics as M
from m3c.eval.threedpw_eval import evaluate_3dpw, format_3dpw_tables
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.io.manifest import seal


def make_dataset(root, model, rng, people_per_seq=(2, 1), n=12):
    """Sequence files plus the ground-truth parameters used to write them."""
    folder = root / "sequenceFiles" / "test"
    folder.mkdir(parents=True)
    truth = {}
    for s, count in enumerate(people_per_seq):
        name = f"downtown_fake_{s:02d}"
        cam_from_world = np.tile(np.eye(4), (n, 1, 1))
        cam_from_world[:, :3, :3] = Rotation.from_rotvec(np.outer(np.linspace(0, 0.3, n), [0, 1, 0])).as_matrix()
        cam_from_world[:, :3, 3] = [0.0, 0.2, 4.0]
        people = []
        for k in range(count):
            pose = 0.3 * rng.normal(size=(n, 24, 3))
            pose[:, 0] = [np.pi, 0, 0]  # 3DPW's world is y-down like its cameras: people stand head-down in y
            transl = np.stack([np.linspace(0, 1, n) + k, np.zeros(n), np.linspace(0, 0.5, n)], 1)
            betas = rng.normal(size=10)
            valid = np.ones(n, bool)
            valid[[0, 5]] = False
            people.append(dict(pose=pose, transl=transl, betas=betas, valid=valid))
        data = {"sequence": name, "poses": [p["pose"].reshape(n, 72) for p in people],
                "trans": [p["transl"] for p in people],
                "jointPositions": [model.joints(p["pose"], p["betas"], p["transl"]).reshape(n, 72)
                                   for p in people],
                "poses2d": [np.zeros((n, 3, 18)) for _ in people], "campose_valid": [p["valid"] for p in people],
                "genders": ["m", "f"][:count], "betas": [p["betas"] for p in people], "cam_poses": cam_from_world,
                "cam_intrinsics": np.array([[1000.0, 0, 540], [0, 1000.0, 960], [0, 0, 1]]),
                "img_frame_ids": np.arange(n)}
        with open(folder / f"{name}.pkl", "wb") as fh:
            pickle.dump(data, fh, protocol=2)
        truth[name] = (people, np.linalg.inv(cam_from_world))
    return truth


def write_predictions(folder, name, tracks, world_from_cam):
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {"world_from_cam": world_from_cam}
    for k, (frames, pose, betas, transl) in enumerate(tracks):
        arrays.update({f"track{k}_frames": frames, f"track{k}_root_orient": pose[:, 0],
                       f"track{k}_body_pose": pose[:, 1:].reshape(len(frames), 69), f"track{k}_betas": betas,
                       f"track{k}_transl": transl})
    np.savez(folder / f"{name}.npz", **arrays)


@pytest.fixture
def h36m_regressor(synthetic_body_model, rng):
    reg = rng.uniform(size=(17, synthetic_body_model.num_vertices)) ** 8  # peaked, non-negative
    return reg / reg.sum(1, keepdims=True)


def test_evaluate_3dpw(tmp_path, synthetic_body_model, rng, h36m_regressor):
    model = synthetic_body_model
    models = {"male": model, "female": model, "neutral": model}
    truth = make_dataset(tmp_path / "3DPW", model, rng)
    perfect, noisy = tmp_path / "perfect", tmp_path / "noisy"
    for name, (people, world_from_cam) in truth.items():
        tracks, noisy_tracks = [], []
        for p in reversed(people):  # tracker order differs from the dataset's
            frames = np.arange(2, 12)  # starts late: the alignment trims the ground truth
            tracks.append((frames, p["pose"][frames], p["betas"], p["transl"][frames]))
            pose = p["pose"][frames] + 0.1 * rng.normal(size=p["pose"][frames].shape)
            noisy_tracks.append((frames, pose, p["betas"], p["transl"][frames] + 0.5))
        write_predictions(perfect, name, tracks, world_from_cam)
        # A different world frame and different cameras for the noisy method: only its own cameras matter.
        shift = np.eye(4)
        shift[:3, 3] = [3.0, 0.0, -2.0]
        moved = []
        for frames, pose, betas, transl in noisy_tracks:
            root, tr = transform_smpl(shift, pose[:, 0], transl, rest_root_joint(model, betas))
            moved.append((frames, np.concatenate([root[:, None], pose[:, 1:]], 1), betas, tr))
        write_predictions(noisy, name, moved, shift @ world_from_cam)
    evaluation = evaluate_3dpw(tmp_path / "3DPW", "test", {"Perfect": perfect, "Noisy": noisy,
                                                           "Missing": tmp_path / "none"}, models, h36m_regressor)
    perfect_row = evaluation["methods"]["Perfect"]
    for key in ("pa_mpjpe", "mpjpe", "pve", "accel", "w_mpjpe", "wa_mpjpe", "rte"):
        assert perfect_row[key] == pytest.approx(0.0, abs=1e-6), key
    assert evaluation["methods"]["Missing"]["pa_mpjpe"] is None
    assert evaluation["joints"] == "H36M-14"

    # Independent check of one noisy sequence: J14 from the regressor on the valid common frames.
    name = "downtown_fake_01"
    people, world_from_cam = truth[name]
    p = people[0]
    frames = np.array([2, 3, 4, 6, 7, 8, 9, 10, 11])  # common frames without the invalid frame 5
    reg = h36m_regressor[list(H36M_TO_J14)]
    cam_from_world = np.linalg.inv(world_from_cam[frames])

    def j14_cam(pose, betas, transl):
        root, tr = transform_smpl(cam_from_world, pose[:, 0], transl, rest_root_joint(model, betas))
        verts = model.forward(np.concatenate([root[:, None], pose[:, 1:]], 1), betas, tr).vertices
        return np.einsum("kv,nvc->nkc", reg, verts)

    with np.load(noisy / f"{name}.npz") as z:
        pose_pred = np.concatenate([z["track0_root_orient"][:, None], z["track0_body_pose"].reshape(-1, 23, 3)], 1)
        keep = np.isin(z["track0_frames"], frames)
        pose_pred = pose_pred[keep]
    # The file's world is shifted (a pure translation) and so are its cameras: in the original world the
    # prediction is the noisy pose at the noisy translation.
    pred = j14_cam(pose_pred, p["betas"], p["transl"][frames] + 0.5)
    gt = j14_cam(p["pose"][frames], p["betas"], p["transl"][frames])
    row = evaluation["sequences"][name]["Noisy"]
    assert row.mean("pa_mpjpe") == pytest.approx(M.pa_mpjpe(pred, gt).mean(), rel=1e-9)
    assert row.mean("mpjpe") == pytest.approx(M.mpjpe(pred, gt, J14_PELVIS).mean(), rel=1e-9)
    assert row.mean("mpjpe") > 0

    text = format_3dpw_tables(evaluation)
    assert "downtown_fake_00^2" in text and "Noisy: PA-MPJPE" in text


def test_m3c_run_folders_are_read_as_predictions(tmp_path, synthetic_body_model, rng):
    import json

    from m3c.io.results import SCHEMA

    model = synthetic_body_model
    truth = make_dataset(tmp_path / "3DPW", model, rng)
    runs = tmp_path / "runs"
    for name, (people, world_from_cam) in truth.items():
        # `m3c run --frames 0::2` output: every other frame processed, people valid from frame 2 on.
        frame_ids = np.arange(0, 12, 2)
        P, T = len(people), len(frame_ids)
        valid = np.tile(frame_ids >= 2, (P, 1))
        arrays = {"frame_ids": frame_ids, "world_from_cam": world_from_cam[frame_ids], "track_ids": np.arange(P),
                  "valid": valid, "betas": np.stack([p["betas"] for p in people]),
                  "world_root_orient": np.full((P, T, 3), np.nan), "body_pose": np.full((P, T, 23, 3), np.nan),
                  "world_transl": np.full((P, T, 3), np.nan)}
        for k, p in enumerate(people):
            arrays["world_root_orient"][k, valid[k]] = p["pose"][frame_ids[valid[k]], 0]
            arrays["body_pose"][k, valid[k]] = p["pose"][frame_ids[valid[k]], 1:]
            arrays["world_transl"][k, valid[k]] = p["transl"][frame_ids[valid[k]]]
        (runs / name).mkdir(parents=True)
        np.savez(runs / name / "results.npz", **arrays)
        (runs / name / "results.json").write_text(json.dumps({"schema": SCHEMA}))
        seal(runs / name, ["results.npz", "results.json"])  # as `m3c run` would publish them
    models = {"male": model, "female": model, "neutral": model}
    evaluation = evaluate_3dpw(tmp_path / "3DPW", "test", {"M3C": runs}, models)
    row = evaluation["methods"]["M3C"]
    for key in ("pa_mpjpe", "mpjpe", "w_mpjpe"):
        assert row[key] == pytest.approx(0.0, abs=1e-6), key
    # Frames the run skipped are not predictions: each person is evaluated on the 5 processed frames.
    result = evaluation["sequences"]["downtown_fake_00"]["M3C"]
    assert result.mean("pa_mpjpe") == pytest.approx(0.0, abs=1e-6)
