"""`m3c train pose-prior` on a tiny corpus (the two shipped CMU clips): the loss falls, a resumed run ends
where the uninterrupted one does, the weights load through load_vposer, and the held-out evaluation's Gaussian
baseline is checked against a hand computation."""

import json

import numpy as np
import pytest
import torch

from m3c.cli import main
from m3c.eval.benchmark import shipped_clip_paths
from m3c.eval.retarget import RetargetedMotion
from m3c.io.atomic import save_npz_atomic
from m3c.models.vposer import VPoserV2, load_vposer
from m3c.training.common import JointKinematics
from m3c.training.pose_prior import (GaussianPosePrior, PosePriorConfig, body_poses, mirror_poses,
                                     reconstruction_errors, train_pose_prior)


@pytest.fixture
def tiny_corpus(tmp_path):
    """A corpus folder as `m3c data mocap` writes it: 131_01 for training, 01_01 held out."""
    out = tmp_path / "corpus"
    for path in shipped_clip_paths():
        clip = RetargetedMotion.load(path)
        save_npz_atomic(out / "clips" / f"{path.stem}.npz", pose=clip.pose().astype(np.float32),
                        transl=clip.transl.astype(np.float32), betas=clip.betas.astype(np.float32),
                        fps=np.float32(clip.fps), clip=np.array(path.stem))
    (out / "split.json").write_text(json.dumps({"train": ["cmu_131_01"], "held_out": ["cmu_01_01"]}))
    return out


def test_mirror_poses_is_an_involution(rng):
    pose = rng.normal(scale=0.4, size=(5, 24, 3))
    np.testing.assert_allclose(mirror_poses(mirror_poses(pose)), pose)
    assert np.allclose(mirror_poses(pose)[:, 1, 0], pose[:, 2, 0])   # left hip's flexion <- right hip's


def test_train_pose_prior_lowers_the_loss_and_resumes_exactly(tiny_corpus, tmp_path, open_model,
                                                              one_torch_thread):
    from m3c.mocap.corpus import load_corpus

    poses = body_poses(load_corpus(tiny_corpus, "train"), mirror=True)
    assert poses.shape == (2 * 248, 21, 3)
    config = PosePriorConfig(steps=60, batch_size=64, hidden=64, history_every=10, checkpoint_minutes=100.0)
    whole = train_pose_prior(poses, tmp_path / "whole", open_model, config, log=None)
    losses = [h["loss"] for h in whole["history"]]
    assert len(losses) == 6 and losses[-1] < 0.6 * losses[0]
    train_pose_prior(poses, tmp_path / "split", open_model, config, log=None, stop_after=25)
    assert torch.load(tmp_path / "split" / "checkpoint.pt", weights_only=False)["step"] == 25
    resumed = train_pose_prior(poses, tmp_path / "split", open_model, config, resume=True, log=None)
    assert resumed["steps_done"] == 60
    a = torch.load(tmp_path / "whole" / "vposer_v2.ckpt", weights_only=False)["state_dict"]
    b = torch.load(tmp_path / "split" / "vposer_v2.ckpt", weights_only=False)["state_dict"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="other settings"):
        other = PosePriorConfig(steps=61, batch_size=64, hidden=64)
        train_pose_prior(poses, tmp_path / "split", open_model, other, resume=True, log=None)


def test_gaussian_baseline_and_errors_hand_computed(open_model, rng):
    train = rng.normal(scale=0.3, size=(400, 21, 3))
    gauss = GaussianPosePrior(train, dim=63)             # every component: reconstruction is exact
    np.testing.assert_allclose(gauss.reconstruct(train[:10]), train[:10], atol=1e-9)
    from m3c.training.pose_prior import axis_angle_to_matrix_np

    rot = axis_angle_to_matrix_np(np.zeros((2, 21, 3)))
    bent = rot.copy()
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    bent[:, 3] = [[1, 0, 0], [0, c, -s], [0, s, c]]      # left knee (SMPL joint 4) bent 30 degrees
    kin = JointKinematics.from_model(open_model)
    errors = reconstruction_errors(bent, rot, kin)
    assert errors["rotation_deg"] == pytest.approx(30.0 / 21.0, rel=1e-5)
    rest = open_model.joints(np.zeros((1, 24, 3)), np.zeros(10))[0]
    # Ankle and toe swing about the knee's x axis: each moves by the chord of 30 degrees at its distance
    # from it.
    shin, foot = np.linalg.norm((rest[7] - rest[4])[1:]), np.linalg.norm((rest[10] - rest[4])[1:])
    chord = 2 * np.sin(np.radians(15))
    assert errors["joint_mm"] == pytest.approx((shin + foot) * chord / 24 * 1000, rel=1e-4)


def test_train_pose_prior_cli(tiny_corpus, tmp_path, capsys, one_torch_thread):
    out = tmp_path / "prior"
    assert main(["train", "pose-prior", str(tiny_corpus), "--out", str(out), "--steps", "20", "--batch-size",
                 "64", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "vposer" in printed and "gaussian_pca32" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["train_clips"] == 1 and metrics["held_out"]["held_out_poses"] == 300
    model = load_vposer(out / "vposer_v2.ckpt", version="v2")
    assert isinstance(model, VPoserV2)
    assert main(["train", "pose-prior", str(tmp_path), "--out", str(out), "--steps", "2"]) == 2
