"""`m3c train regressor`: the virtual cameras project as m3c.camera and a plain pinhole do, the detector-error
sampler reproduces the measured model, a few-step run on a tiny corpus (the two shipped CMU clips) lowers its
loss and a resumed run ends where the uninterrupted one does, and the network keeps WHAM's checkpoint
layout. The residual root orientation holds the previous one under a zero change, and parallel scheduled
sampling becomes the autoregressive network when every frame is fed the network's own outputs."""

import json

import numpy as np
import pytest
import torch

from m3c.camera import world_to_image
from m3c.cli import main
from m3c.eval.benchmark import shipped_clip_paths
from m3c.eval.retarget import RetargetedMotion
from m3c.io.atomic import save_npz_atomic
from m3c.mocap.corpus import foot_contacts, load_corpus
from m3c.models import wham
from m3c.models.rotations import matrix_to_rotation_6d_rows, rotation_6d_to_matrix_rows
from m3c.models.wham import WhamLifter
from m3c.training.detector_errors import load_detector_errors
from m3c.training.regressor import (RegressorConfig, WorldRegressor, evaluate, evaluation_batch,
                                    load_regressor, make_batch, mean_training_targets, own_previous,
                                    prepare_clips, procrustes_mpjpe, run_network, run_teacher_forced,
                                    save_regressor, train_regressor)
from m3c.training.virtual_camera import (MOTIONS, DetectorErrors, VirtualCameraConfig, ar1, project_keypoints,
                                         sample_camera)


@pytest.fixture
def tiny_corpus(tmp_path, open_model):
    """A corpus folder as `m3c data mocap` writes it: 131_01 for training, 01_01 held out."""
    out = tmp_path / "corpus"
    for path in shipped_clip_paths():
        clip = RetargetedMotion.load(path)
        pose = clip.pose()
        joints = open_model.joints(pose, clip.betas, clip.transl)
        save_npz_atomic(out / "clips" / f"{path.stem}.npz", pose=pose.astype(np.float32),
                        transl=clip.transl.astype(np.float32), betas=clip.betas.astype(np.float32),
                        contacts=foot_contacts(joints, clip.fps, 0.06, 0.3), fps=np.float32(clip.fps),
                        clip=np.array(path.stem))
    (out / "split.json").write_text(json.dumps({"train": ["cmu_131_01"], "held_out": ["cmu_01_01"]}))
    return out


def _walk(n=40, fps=30.0):
    t = np.arange(n) / fps
    return np.stack([1.3 * t, np.full(n, 0.95), 0.2 * t], axis=1)


@pytest.mark.parametrize("motion", MOTIONS)
def test_virtual_camera_projects_as_m3c_camera_and_a_plain_pinhole(motion, rng):
    pelvis = _walk()
    camera = sample_camera(rng, pelvis, 30.0, VirtualCameraConfig(), motion)
    assert camera["motion"] == motion
    poses, k = camera["world_from_cam"], camera["intrinsics"]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", poses[:, :3, :3], poses[:, :3, :3]),
                               np.broadcast_to(np.eye(3), (len(poses), 3, 3)), atol=1e-12)
    points = pelvis[:, None] + rng.normal(scale=0.4, size=(len(pelvis), 17, 3))
    pixels, depth = project_keypoints(points, poses, k)
    for t in (0, len(pelvis) // 2, len(pelvis) - 1):
        ref, ref_depth = world_to_image(points[t], poses[t], k)
        np.testing.assert_allclose(pixels[t], ref, atol=1e-9)
        np.testing.assert_allclose(depth[t], ref_depth, atol=1e-12)
    # An independent pinhole: X_cam = R^T (X - c), u = K X_cam / z.
    R, c = poses[:, :3, :3], poses[:, :3, 3]
    cam = np.stack([(points[t] - c[t]) @ R[t] for t in range(len(points))])
    K = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1.0]])
    homogeneous = cam @ K.T
    np.testing.assert_allclose(pixels, homogeneous[..., :2] / homogeneous[..., 2:], rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(depth, cam[..., 2], atol=1e-12)
    assert (depth[:, 0] > 0).all()        # the person is in front of the camera


def test_camera_motions_move_as_named(rng):
    pelvis, config = _walk(), VirtualCameraConfig(aim_offset=0.0)
    static = sample_camera(rng, pelvis, 30.0, config, "static")["world_from_cam"]
    np.testing.assert_allclose(static, np.broadcast_to(static[0], static.shape))
    pan = sample_camera(rng, pelvis, 30.0, config, "pan")["world_from_cam"]
    np.testing.assert_allclose(pan[:, :3, 3], np.broadcast_to(pan[0, :3, 3], (len(pan), 3)))
    assert not np.allclose(pan[0, :3, :3], pan[-1, :3, :3])                  # it turns
    follow = sample_camera(rng, pelvis, 30.0, config, "follow")["world_from_cam"]
    assert np.linalg.norm(follow[-1, :3, 3] - follow[0, :3, 3]) > 0.3        # it travels with the person
    orbit = sample_camera(rng, pelvis, 30.0, config, "orbit")["world_from_cam"]
    forward = orbit[:, :3, 2] * [1, 0, 1]
    turned = np.degrees(np.arccos(np.clip((forward[0] @ forward[-1]) / np.linalg.norm(forward[0])
                                          / np.linalg.norm(forward[-1]), -1, 1)))
    assert turned > 5.0 * (len(pelvis) - 1) / 30.0 * 0.5                      # at least half the slowest rate
    heights = [sample_camera(rng, pelvis, 30.0, config)["world_from_cam"][0, 1, 3] for _ in range(50)]
    assert config.height[0] <= min(heights) and max(heights) <= config.height[1]


def test_ar1_has_unit_variance_and_the_asked_correlation(rng):
    x = ar1(rng, 48, (4000, 2), np.array([0.3, 0.9]))
    assert x.std(axis=(0, 1)) == pytest.approx([1.0, 1.0], abs=0.03)
    lag = (x[1:] * x[:-1]).mean(axis=(0, 1))
    assert lag == pytest.approx([0.3, 0.9], abs=0.03)


def test_detector_errors_reproduce_the_measured_model(rng):
    model = load_detector_errors()
    assert len(model["sequences"]) >= 5 and len(model["error_quantiles"]) == 17
    errors, config = DetectorErrors(model), VirtualCameraConfig(occlusion_prob=0.0)
    n = 48
    pixels = np.tile(rng.uniform(200, 400, size=(1, 17, 2)), (n, 1, 1))
    pixels[:, 0] = [300.0, 150.0]
    pixels[:, 16] = [300.0, 450.0]                                           # the box is 300 px tall
    depth = np.full((n, 17), 4.0)
    depth[:, 5] = -1.0                                                       # behind the camera
    pixels[:, 9] = [2000.0, 300.0]                                           # outside the image
    measured, confidence = [], []
    for _ in range(300):
        det = errors.corrupt(rng, pixels, depth, (960, 540), config)
        measured.append(np.linalg.norm(det["keypoints"] - pixels, axis=-1) / det["box"][:, 2:])
        confidence.append(det["confidence"])
    measured, confidence = np.concatenate(measured), np.concatenate(confidence)
    assert not confidence[:, [5, 9]].any()                                   # truncated keypoints are masked
    medians = np.median(measured, axis=0)
    expected = np.array(model["error_quantiles"])[:, 10]
    np.testing.assert_allclose(medians, expected, rtol=0.1)
    keep = [j for j in range(17) if j not in (5, 9)]
    missing = 1.0 - confidence[:, keep].mean(0)
    np.testing.assert_allclose(missing, np.array(model["missing_rate"])[keep], atol=0.03)


def test_procrustes_ignores_similarity_transforms(rng):
    from scipy.spatial.transform import Rotation

    true = rng.normal(size=(5, 24, 3))
    R = Rotation.random(5, random_state=1).as_matrix()
    moved = 1.7 * np.einsum("nij,nkj->nki", R, true) + rng.normal(size=(5, 1, 3))
    np.testing.assert_allclose(procrustes_mpjpe(moved, true), 0.0, atol=1e-9)
    assert (procrustes_mpjpe(true + 0.1 * rng.normal(size=true.shape), true) > 0.05).all()


def test_regressor_keeps_whams_layout():
    small, official = WorldRegressor(512).state_dict(), WhamLifter().state_dict()
    assert set(small) <= set(official)
    assert all(small[k].shape == official[k].shape for k in small)
    assert any(k.startswith("motion_decoder.") for k in small)


@pytest.mark.parametrize("formulation", [dict(root="absolute"), dict(root="residual", sampling_passes=2)])
def test_training_lowers_the_loss_and_resumes_exactly(formulation, tiny_corpus, tmp_path, open_model,
                                                      one_torch_thread):
    clips = prepare_clips(load_corpus(tiny_corpus, "train"), open_model, 12)
    config = RegressorConfig(steps=40, batch_size=8, frames=12, width=24, lr=3e-3, history_every=8,
                             checkpoint_minutes=100.0, **formulation)
    whole = train_regressor(clips, tmp_path / "whole", open_model, config, log=None)
    losses = [h["loss"] for h in whole["history"]]
    assert len(losses) == 5 and losses[-1] < 0.6 * losses[0]
    train_regressor(clips, tmp_path / "split", open_model, config, log=None, stop_after=15)
    assert torch.load(tmp_path / "split" / "checkpoint.pt", weights_only=False)["step"] == 15
    resumed = train_regressor(clips, tmp_path / "split", open_model, config, resume=True, log=None)
    assert resumed["steps_done"] == 40
    a = load_regressor(tmp_path / "whole" / "regressor.pt")
    b = load_regressor(tmp_path / "split" / "regressor.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))
    assert a.root == b.root == config.root
    with pytest.raises(ValueError, match="other settings"):
        other = RegressorConfig(steps=41, batch_size=8, frames=12, width=24, **formulation)
        train_regressor(clips, tmp_path / "split", open_model, other, resume=True, log=None)


def test_evaluation_scores_the_truth_perfectly(tiny_corpus, open_model):
    from m3c.training.common import JointKinematics

    config = RegressorConfig(frames=12, width=16)
    clips = prepare_clips(load_corpus(tiny_corpus, "held_out"), open_model, config.frames)
    batch = evaluation_batch(clips, config, windows=6)
    again = evaluation_batch(clips, config, windows=6)
    assert all(torch.equal(batch[k], again[k]) for k in batch)              # a fixed evaluation set
    assert batch["x"].shape == (6, 12, 37) and batch["pose"].shape == (6, 12, 24, 3, 3)

    class Oracle(WorldRegressor):
        def forward(self, x, mask, init_kp, init_root, cam_angvel, init_pose):
            return {"pose": matrix_to_rotation_6d_rows(batch["pose"]).double(),
                    "root_6d": torch.cat([init_root, matrix_to_rotation_6d_rows(batch["root"])], 1).double(),
                    "velocity": batch["velocity"].double(), "contact": 10 * (2 * batch["contacts"] - 1),
                    "keypoints_3d": batch["kp3d"]}

    report = evaluate(Oracle(16), batch, JointKinematics.from_model(open_model),
                      mean_training_targets(clips, config, windows=4), chunk=100)
    r, base = report["regressor"], report["baselines"]
    assert r["pa_mpjpe_mm"] < 1e-3 and r["velocity_mps"] < 1e-4 and r["root_deg"] < 0.1
    assert r["contact_f1"] == pytest.approx(1.0) and r["kp3d_mpjpe_mm"] < 1e-3
    assert base["mean_pose_pa_mpjpe_mm"] > 10 and base["init_pose_pa_mpjpe_mm"] > 10


def test_train_regressor_command(tiny_corpus, tmp_path, open_model, one_torch_thread, capsys):
    out = tmp_path / "run"
    assert main(["train", "regressor", str(tiny_corpus), "--out", str(out), "--steps", "3", "--batch-size",
                 "4", "--frames", "10", "--width", "16", "--eval-windows", "4", "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 3 and metrics["held_out"]["windows"] == 4
    assert set(metrics["held_out"]["regressor"]) >= {"pa_mpjpe_mm", "velocity_mps", "contact_f1"}
    assert "PA-MPJPE" in capsys.readouterr().out
    net = load_regressor(out / "regressor.pt")
    batch = make_batch(np.random.default_rng(0), prepare_clips(load_corpus(tiny_corpus, "train"),
                                                               open_model, 10), RegressorConfig(frames=10),
                       DetectorErrors(), size=2)
    with torch.no_grad():
        assert net(batch["x"], batch["mask"], batch["init_kp"], batch["init_root"], batch["angvel"],
                   batch["init_pose"])["pose"].shape == (2, 10, 24, 6)



def _batch(tiny_corpus, open_model, frames=10, size=3):
    clips = prepare_clips(load_corpus(tiny_corpus, "train"), open_model, frames)
    return make_batch(np.random.default_rng(2), clips, RegressorConfig(frames=frames), DetectorErrors(), size)


def _untrained(root):
    """A small network whose orientation head is not zero (a fresh residual one's is): its reading shows."""
    torch.manual_seed(0)
    net = WorldRegressor(16, root).eval()
    torch.nn.init.normal_(net.trajectory_decoder.regressor.declayer1.weight, std=0.05)
    return net


@pytest.mark.parametrize("root", ["absolute", "residual"])
def test_teacher_forcing_with_its_own_outputs_is_the_autoregressive_network(root, tiny_corpus, open_model):
    batch = _batch(tiny_corpus, open_model)
    net = _untrained(root)
    with torch.no_grad():
        out = run_network(net, batch)
        forced = net.teacher_forced(batch["x"], batch["mask"], batch["init_kp"], batch["init_root"],
                                    batch["angvel"], batch["init_pose"], own_previous(batch, out))
    for key in ("keypoints_3d", "root_6d", "velocity", "pose", "betas", "contact"):
        torch.testing.assert_close(forced[key], out[key], rtol=1e-5, atol=1e-5)


def test_residual_root_holds_the_previous_orientation_under_a_zero_change(tiny_corpus, open_model, rng):
    from scipy.spatial.transform import Rotation

    previous = torch.as_tensor(Rotation.random(5, random_state=3).as_matrix())
    change = torch.as_tensor(Rotation.from_rotvec(0.2 * rng.normal(size=(5, 3))).as_matrix())
    p6 = matrix_to_rotation_6d_rows(previous)
    torch.testing.assert_close(wham.compose_root(p6, torch.zeros_like(p6)), p6, rtol=0, atol=1e-12)
    identity = torch.tensor(wham.IDENTITY_6D, dtype=p6.dtype)
    delta = matrix_to_rotation_6d_rows(change) - identity
    composed = rotation_6d_to_matrix_rows(wham.compose_root(p6, delta))
    torch.testing.assert_close(composed, previous @ change, rtol=0, atol=1e-12)     # on the right
    # An untrained residual network holds the initial orientation over the window; an absolute one does not.
    batch = _batch(tiny_corpus, open_model)
    torch.manual_seed(0)
    with torch.no_grad():
        held = run_network(WorldRegressor(16, "residual").eval(), batch)["root_6d"]
        free = run_network(WorldRegressor(16, "absolute").eval(), batch)["root_6d"]
    init = batch["init_root"].expand_as(held)
    torch.testing.assert_close(held, init, rtol=0, atol=1e-6)
    assert (free[:, 1:] - init[:, 1:]).abs().max() > 0.1
    assert not wham.TrajectoryDecoder().residual and not WhamLifter().trajectory_decoder.residual


def test_scheduled_sampling_on_every_frame_is_the_autoregressive_network(tiny_corpus, open_model):
    batch = _batch(tiny_corpus, open_model)
    f = batch["x"].shape[1]
    net = _untrained("residual")
    with torch.no_grad():
        out = run_network(net, batch)
        # With prob 1, pass k is exact on the first k + 1 frames: f - 1 passes make the whole window so.
        exact = run_teacher_forced(net, batch, 0.0, passes=f - 1, prob=1.0)
        short = run_teacher_forced(net, batch, 0.0, passes=f - 3, prob=1.0)
        none = run_teacher_forced(net, batch, 0.0, passes=f - 1, prob=0.0)
        forced = run_teacher_forced(net, batch, 0.0)
    for key in ("keypoints_3d", "root_6d", "velocity", "pose", "contact"):
        torch.testing.assert_close(exact[key], out[key], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(none[key], forced[key], rtol=0, atol=0)
    # Fewer passes: exact on the first f - 2 frames only (the residual root carries an error on unshrunk; an
    # untrained pose decoder barely reads its previous pose).
    root, true_root = short["root_6d"][:, 1:], out["root_6d"][:, 1:]
    torch.testing.assert_close(root[:, :f - 2], true_root[:, :f - 2], rtol=1e-5, atol=1e-5)
    assert (root[:, -1] - true_root[:, -1]).abs().max() > 1e-3


def test_regressor_files_carry_their_root_formulation(tiny_corpus, tmp_path, open_model, one_torch_thread):
    net = _untrained("absolute")
    save_regressor(net, tmp_path / "absolute.pt")
    assert load_regressor(tmp_path / "absolute.pt").root == "absolute"
    # A file from before the flag was trained absolute.
    state = torch.load(tmp_path / "absolute.pt", weights_only=False)
    del state["formulation"]
    torch.save(state, tmp_path / "old.pt")
    old = load_regressor(tmp_path / "old.pt")
    assert old.root == "absolute" and not old.trajectory_decoder.residual
    clips = prepare_clips(load_corpus(tiny_corpus, "train"), open_model, 10)
    config = RegressorConfig(steps=1, batch_size=2, frames=10, width=16, root="residual")
    with pytest.raises(ValueError, match="reads its root orientation as 'absolute'"):
        train_regressor(clips, tmp_path / "run", open_model, config, log=None, init=tmp_path / "old.pt")
    with pytest.raises(ValueError, match="unknown root formulation"):
        WorldRegressor(16, "camera")


def test_look_at_many_is_look_at_row_by_row(rng):
    from m3c.camera import look_at
    from m3c.training.virtual_camera import look_at_many

    eyes, targets = rng.normal(size=(20, 3)) * 3, rng.normal(size=(20, 3))
    expected = np.stack([look_at(e, t) for e, t in zip(eyes, targets)])
    np.testing.assert_allclose(look_at_many(eyes, targets), expected, atol=1e-12)


def test_root_noise_perturbs_the_previous_root_orientation_alone(tiny_corpus, open_model):
    batch = _batch(tiny_corpus, open_model)
    net = _untrained("residual")
    for p in net.trajectory_decoder.regressor.declayer1.parameters():   # a head that turns (zero holds)
        torch.nn.init.normal_(p, std=0.01)
    runs = {}
    with torch.no_grad():
        for name, root_noise in (("same", None), ("zero", 0.0), ("large", 0.5)):
            torch.manual_seed(0)
            runs[name] = run_teacher_forced(net, batch, 0.0, root_noise=root_noise)
    for key in ("keypoints_3d", "pose"):        # the encoder and motion decoder never read the root
        torch.testing.assert_close(runs["large"][key], runs["zero"][key], rtol=0, atol=0)
    for key in runs["zero"]:
        torch.testing.assert_close(runs["same"][key], runs["zero"][key], rtol=0, atol=0)
    assert (runs["large"]["root_6d"] - runs["zero"]["root_6d"]).abs().max() > 0.05


def test_shipping_a_regressor_records_figures_its_sample_reproduces(tiny_corpus, tmp_path, open_model,
                                                                   one_torch_thread):
    from m3c.mocap.corpus import LICENCES
    from m3c.training.ship import regressor_sample_figures, ship_regressor
    from m3c.training.regressor import config_from_dict

    for path in (tiny_corpus / "clips").glob("*.npz"):       # the CMU licence `m3c data mocap` records
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        save_npz_atomic(path, **arrays, licence=np.array(LICENCES["cmu"]))
    run = tmp_path / "run"
    assert main(["train", "regressor", str(tiny_corpus), "--out", str(run), "--steps", "2", "--batch-size", "4",
                 "--frames", "10", "--width", "16", "--eval-windows", "4", "--quiet"]) == 0
    dest = tmp_path / "weights"
    card = ship_regressor(run, tiny_corpus, dest, "the command")
    assert json.loads((dest / "regressor.json").read_text()) == json.loads(json.dumps(card))
    assert "# M3C world regressor (`regressor.pt`)" in (dest / "MODEL_CARD.md").read_text()
    assert card["sample"]["clips"] == 1 and card["sample"]["windows"] == 64
    with np.load(dest / "regressor_sample.npz") as z:
        assert str(z["clips"][0]) == "cmu_01_01" and len(z["pose"]) == min(300, z["lengths"][0])
        clip = {"pose": z["pose"], "transl": z["transl"], "contacts": z["contacts"], "betas": z["betas"][0],
                "fps": z["fps"][0]}
        means = {"pose": z["mean_pose"], "velocity": z["mean_velocity"]}
    got = regressor_sample_figures(load_regressor(dest / "regressor.pt"), [clip], open_model,
                                   config_from_dict(card["config"]), means)
    assert got["regressor"] == pytest.approx(card["sample"]["regressor"], rel=1e-6)
    assert got["baselines"] == pytest.approx(card["sample"]["baselines"], rel=1e-6)
