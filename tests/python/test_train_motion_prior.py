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
from m3c.models.export import export_weights
from m3c.models.humor import transition_nll
from m3c.nn import HumorPrior
from m3c.training.motion_prior import (CHANGE_DIM, MotionPrior, MotionPriorConfig, clip_states,
                                       constant_velocity_change, load_motion_prior, one_step_errors, pairs,
                                       planted_sliding, rollout_figures, start_states, state_change,
                                       train_motion_prior)


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
    config = MotionPriorConfig(steps=80, batch_size=64, hidden=64, lr=2e-3, history_every=10,
                               checkpoint_minutes=100.0)
    data = pairs(_clips()[:1], open_model, config)
    whole = train_motion_prior(data, tmp_path / "whole", config, log=None)
    losses = [h["loss"] for h in whole["history"]]
    assert len(losses) == 8 and losses[-1] < 0.8 * losses[0]
    train_motion_prior(data, tmp_path / "split", config, log=None, stop_after=35)
    resumed = train_motion_prior(data, tmp_path / "split", config, resume=True, log=None)
    assert resumed["steps_done"] == 80
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


def test_change_is_what_the_decoder_layout_applies(open_model):
    x_prev, x_next, _ = pairs(_clips()[1:], open_model, MotionPriorConfig())
    x_prev, x_next = x_prev[:50].double(), x_next[:50].double()
    change = state_change(x_prev, x_next)
    back, _ = hs.apply_decoder_output(x_prev, torch.cat([change, torch.zeros(50, 9, dtype=torch.float64)], -1))
    np.testing.assert_allclose(back.numpy(), x_next.numpy(), atol=1e-6)
    # Constant velocity by hand: the joints move on by their velocity for 1/30 s, the body's rotations stay.
    cv = constant_velocity_change(x_prev)
    np.testing.assert_allclose(cv[:, hs.OUT_JOINTS].numpy(), x_prev[:, hs.JOINTS_VEL].numpy() / 30.0, atol=1e-12)
    assert torch.count_nonzero(cv[:, hs.OUT_POSE_BODY]) == 0 and cv.shape == (50, CHANGE_DIM)


def test_untrained_decoder_is_constant_velocity_and_the_export_folds_exactly(open_model, tmp_path):
    x_prev, x_next, _ = pairs(_clips()[1:], open_model, MotionPriorConfig())
    torch.manual_seed(0)
    model = MotionPrior(64).double()
    model.set_normalisation(x_prev.double(), x_next.double())
    model.eval()
    errors = one_step_errors(model, x_prev.double(), x_next.double())
    assert errors["motion_prior_mm"] == pytest.approx(errors["constant_velocity_mm"], rel=1e-9)
    # The C++ runtime reads the folded encoder and prior: the same transition likelihood as the torch model.
    export_weights(tmp_path, humor=model, dtype="float64")
    cpp = HumorPrior(tmp_path / "humor.safetensors")
    a, b = x_prev[:20].double(), x_next[:20].double()
    with torch.no_grad():
        expected = transition_nll(model, a, b).numpy()
        folded = transition_nll(model.official_layout(), a, b).numpy()
    np.testing.assert_allclose(folded, expected, rtol=1e-9)
    np.testing.assert_allclose(cpp.transition_nll(a.numpy(), b.numpy()), expected, rtol=1e-8)
    with pytest.raises(ValueError, match="without the decoder"):
        export_weights(tmp_path / "dec", humor=model, include_humor_decoder=True)


def test_planted_sliding_by_hand():
    feet = np.zeros((1, 10, 1, 3))
    feet[0, :, 0, 0] = np.arange(10) * 0.01          # 1 cm a frame along x
    planted = np.zeros((1, 10, 1), bool)
    planted[0, 1:5, 0] = True                          # 4 frames planted: 3 cm
    planted[0, 7:9, 0] = True                          # 2 frames: too short to count
    np.testing.assert_allclose(planted_sliding(feet, planted), [0.03])


def test_rollouts_of_an_untrained_prior_keep_walking(open_model):
    clips = _clips()
    starts = start_states(clips, open_model, MotionPriorConfig(), count=4, seed=1)
    model = MotionPrior(64)
    x_prev, x_next, _ = pairs(clips, open_model, MotionPriorConfig())
    model.set_normalisation(x_prev, x_next)
    torch.manual_seed(0)
    figures = rollout_figures(model.eval(), starts, seconds=1.0)
    # Constant velocity (the untrained decoder) for a second: finite, the feet near the floor they started on.
    assert figures["finite"] and figures["samples"] == 4
    assert -10 < figures["lowest_foot_cm_median"] < 20


def test_rollout_windows_and_loss(open_model, tmp_path, one_torch_thread):
    from m3c.training.motion_prior import _loss, _rollout_loss, train_motion_prior_rollouts, windows

    clips = _clips()[:1]
    config = MotionPriorConfig(rollout_steps=4, hidden=64, batch_size=16, steps=6, history_every=3,
                               checkpoint_minutes=100.0)
    states, contacts = windows(clips, open_model, config)
    full, labels = clip_states(clips[0], open_model, config)
    # Windows of 5 consecutive states, stride 4, with the contacts of states 1..4.
    assert states.shape[1:] == (5, hs.STATE_DIM) and len(states) == (len(full) - 4 + 3) // 4
    torch.testing.assert_close(states[2], full[8:13])
    torch.testing.assert_close(contacts[2], labels[9:13])
    # One transition from the truth is the pair loss exactly (same latent noise).
    model = MotionPrior(64)
    model.set_normalisation(*pairs(clips, open_model, config)[:2])
    one = MotionPriorConfig(**{**config.__dict__, "rollout_steps": 1})
    a, b = hs.canonicalize_pair(states[:8, 0], states[:8, 1])
    torch.manual_seed(3)
    expected = _loss(model, a, b, contacts[:8, 0], one, step=10 ** 6)
    torch.manual_seed(3)
    got = _rollout_loss(model, states[:8, :2], contacts[:8, :1], one, step=10 ** 6)
    for key in ("loss", "rec", "contact", "kl"):
        torch.testing.assert_close(got[key], expected[key])
    summary = train_motion_prior_rollouts((states, contacts), tmp_path / "roll", config, log=None)
    assert summary["steps_done"] == 6 and load_motion_prior(tmp_path / "roll" / "motion_prior.pt").hidden == 64
