"""`m3c train motion-prior` on a tiny corpus (the two shipped CMU clips): HuMoR-layout networks whose loss
falls, a resumed run that ends where the uninterrupted one does, states and contact labels checked by hand,
and the one-step figures against constant velocity computed independently."""

import json

import numpy as np
import pytest
import torch

from m3c.cli import main
from m3c.eval.benchmark import shipped_clip_paths
from m3c.eval.retarget import RetargetedMotion
from m3c.io.atomic import save_npz_atomic
from m3c.models import humor_state as hs
from m3c.training.motion_prior import (MotionPrior, MotionPriorConfig, clip_states, load_motion_prior,
                                       one_step_errors, pairs, train_motion_prior)


def _clips():
    out = []
    for path in shipped_clip_paths():
        clip = RetargetedMotion.load(path)
        out.append({"pose": clip.pose().astype(np.float32), "transl": clip.transl.astype(np.float32),
                    "betas": clip.betas.astype(np.float32), "fps": np.float32(clip.fps),
                    "clip": np.array(path.stem)})
    return out


def test_states_are_in_the_ground_frame_with_contacts(open_model):
    clip = _clips()[0]
    states, contacts = clip_states(clip, open_model, MotionPriorConfig())
    assert states.shape == (len(clip["pose"]) - 2, hs.STATE_DIM) and contacts.shape == (len(states), 9)
    joints = open_model.joints(clip["pose"].astype(np.float64), clip["betas"], clip["transl"])[1:-1, :22]
    # Ground frame: z up (the world's y), the floor at z = 0.
    got = states[:, hs.JOINTS].reshape(-1, 22, 3).double().numpy()
    np.testing.assert_allclose(got[..., 2], joints[..., 1], atol=1e-4)
    feet = got[:, [10, 11], 2]
    assert np.all(feet.min(axis=0) > -0.05) and np.all(feet.min(axis=0) < 0.1)
    assert 0.2 < contacts[:, 5:7].mean() < 0.9      # the walker's toes: planted part of the time


def test_train_motion_prior_lowers_the_loss_and_resumes_exactly(open_model, tmp_path, one_torch_thread):
    config = MotionPriorConfig(steps=40, batch_size=64, hidden=64, history_every=10, checkpoint_minutes=100.0)
    data = pairs(_clips()[:1], open_model, config)
    whole = train_motion_prior(data, tmp_path / "whole", config, log=None)
    losses = [h["loss"] for h in whole["history"]]
    assert len(losses) == 4 and losses[-1] < 0.8 * losses[0]
    train_motion_prior(data, tmp_path / "split", config, log=None, stop_after=15)
    resumed = train_motion_prior(data, tmp_path / "split", config, resume=True, log=None)
    assert resumed["steps_done"] == 40
    a, b = (load_motion_prior(tmp_path / d / "motion_prior.pt").state_dict() for d in ("whole", "split"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="multiple of 32"):
        MotionPrior(40)


def test_one_step_errors_constant_velocity_by_hand(open_model):
    x_prev, x_next, _ = pairs(_clips()[1:], open_model, MotionPriorConfig())
    errors = one_step_errors(MotionPrior(64).eval(), x_prev, x_next)
    j0 = x_prev[:, hs.JOINTS].reshape(-1, 22, 3).numpy()
    v0 = x_prev[:, hs.JOINTS_VEL].reshape(-1, 22, 3).numpy()
    j1 = x_next[:, hs.JOINTS].reshape(-1, 22, 3).numpy()
    expected = np.linalg.norm(j0 + v0 / 30.0 - j1, axis=-1).mean() * 1000
    assert errors["constant_velocity_mm"] == pytest.approx(expected, rel=1e-4)
    assert errors["pairs"] == len(x_prev) and errors["motion_prior_mm"] > 0


def test_train_motion_prior_cli(tmp_path, capsys, one_torch_thread):
    corpus = tmp_path / "corpus"
    for clip in _clips():
        save_npz_atomic(corpus / "clips" / f"{clip['clip']}.npz", **clip)
    (corpus / "split.json").write_text(json.dumps({"train": ["cmu_131_01"], "held_out": ["cmu_01_01"]}))
    out = tmp_path / "prior"
    assert main(["train", "motion-prior", str(corpus), "--out", str(out), "--steps", "5", "--batch-size",
                 "32", "--hidden", "64", "--quiet"]) == 0
    assert "constant velocity" in capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["held_out_one_step"]["pairs"] == 300 - 3 and metrics["steps"] == 5
