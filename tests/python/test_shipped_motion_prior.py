"""M3C's shipped motion prior: it loads, meets its recorded held-out figures on the shipped held-out sample (CMU
clips kept out of training), predicts the next frame better than constant velocity, rolls out samples that stay
on the ground with planted feet that hold, and exports to the C++ runtime, which scores transitions as torch
does."""

import json

import numpy as np
import pytest
import torch

from m3c.models.humor import transition_nll
from m3c.models.weights import shipped_motion_prior_path, weights_dir
from m3c.training.motion_prior import MotionPriorConfig, load_motion_prior, pairs
from m3c.training.ship import motion_sample_figures


@pytest.fixture(scope="module")
def shipped():
    prior = load_motion_prior(shipped_motion_prior_path())
    card = json.loads((weights_dir() / "motion_prior.json").read_text())
    with np.load(weights_dir() / "motion_prior_sample.npz") as z:
        data = {k: z[k] for k in z.files}
    clips, start = [], 0
    for i, n in enumerate(data["lengths"]):
        clips.append({"pose": data["pose"][start:start + n], "transl": data["transl"][start:start + n],
                      "betas": data["betas"][i], "fps": data["fps"][i], "clip": data["clips"][i]})
        start += n
    return prior, card, clips


def test_shipped_motion_prior_meets_its_held_out_figures(shipped, open_model, one_torch_thread):
    prior, card, clips = shipped
    assert "non-commercial" in card["licence"] and len(clips) == card["sample"]["clips"]
    config = MotionPriorConfig(**card["config"])
    got = motion_sample_figures(prior, clips, open_model, config)
    recorded = card["sample"]
    for key in ("motion_prior_mm", "constant_velocity_mm"):
        assert got["one_step"][key] == pytest.approx(recorded["one_step"][key], rel=1e-3)
    assert got["one_step"]["motion_prior_mm"] < got["one_step"]["constant_velocity_mm"]
    rollouts = got["rollouts"]
    assert rollouts["finite"]
    for key in ("sliding_cm_median", "lowest_foot_cm_median", "frames_on_ground"):
        assert rollouts[key] == pytest.approx(recorded["rollouts"][key], rel=1e-2, abs=0.05)
    # Not yet the bar the priors issue sets (planted feet under 2 cm a step over 2 s rollouts): trained one step
    # at a time, the prior's own rollouts drift (about 1 cm a frame while planted); the model card says so.


def test_shipped_motion_prior_exports_to_the_cpp_runtime(shipped, open_model, tmp_path, one_torch_thread):
    from m3c.models.export import export_weights
    from m3c.nn import HumorPrior

    prior, card, clips = shipped
    x_prev, x_next, _ = pairs(clips[:1], open_model, MotionPriorConfig(**card["config"]))
    export_weights(tmp_path, humor=prior)
    runtime = HumorPrior(tmp_path / "humor.safetensors")
    a, b = x_prev[:16].double(), x_next[:16].double()
    with torch.no_grad():
        expected = transition_nll(prior.double(), a, b).numpy()
    np.testing.assert_allclose(runtime.transition_nll(a.numpy(), b.numpy()), expected, rtol=1e-4)


def test_the_shipped_motion_prior_is_named_by_optimize(tmp_path, monkeypatch, one_torch_thread):
    from m3c.models.weights import shipped_humor_runtime
    from m3c.nodes.optimize import OptimizeNode

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    path = shipped_humor_runtime()
    assert path.name == "humor.safetensors" and path.is_relative_to(tmp_path)
    stamp = path.stat().st_mtime_ns
    assert shipped_humor_runtime() == path and path.stat().st_mtime_ns == stamp  # reused, not rewritten
    node = OptimizeNode("optimize", OptimizeNode.Config(motion_prior="shipped"))
    assert node._weights(None, "motion_prior", "humor.safetensors") == path
