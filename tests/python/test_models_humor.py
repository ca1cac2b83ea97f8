"""HuMoR in torch: architecture against REFERENCE A, checkpoint loading in the official layout, the MLP against
an independent numpy implementation, and the motion-prior terms against torch.distributions."""

import copy
import math
import os

import numpy as np
import pytest
import torch

from m3c.models import checkpoint as ckpt
from m3c.models import humor_state as hs
from m3c.models.humor import (HumorModel, gaussian_nll, latent_nll, load_humor, sequence_transition_nll,
                              transition_nll)
from m3c.models.rotations import axis_angle_to_matrix
from pickled_names import importable, named_class


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    m = HumorModel().double().eval()
    # GroupNorm starts as the identity affine; random affine parameters make the check meaningful.
    with torch.no_grad():
        for module in m.modules():
            if isinstance(module, torch.nn.GroupNorm):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
    return m.requires_grad_(False)


def random_states(n, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, hs.STATE_DIM, generator=g, dtype=torch.float64) * 0.3
    R = torch.linalg.qr(torch.randn(n, 3, 3, generator=g, dtype=torch.float64))[0]
    R = R * torch.det(R)[:, None, None]  # proper rotations
    x[:, hs.ROOT_ORIENT] = R.reshape(n, 9)
    pose = torch.linalg.qr(torch.randn(n, 21, 3, 3, generator=g, dtype=torch.float64))[0]
    pose = pose * torch.det(pose)[..., None, None]
    x[:, hs.POSE_BODY] = pose.reshape(n, 189)
    return x


def test_parameter_counts_match_reference(model):
    count = lambda m: sum(p.numel() for p in m.parameters())  # noqa: E731
    assert count(model.encoder) == 3_950_688
    assert count(model.prior_net) == 3_603_552
    assert count(model.decoder) == 2_171_736
    assert count(model) == 9_725_976


def test_state_dict_layout_matches_reference(model):
    shapes = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    for net, first in (("encoder", 678), ("prior_net", 339)):
        assert shapes[f"{net}.net.0.weight"] == (1024, first)
        for i in (3, 6, 9):
            assert shapes[f"{net}.net.{i}.weight"] == (1024, 1024)
        for i in (1, 4, 7, 10):
            assert shapes[f"{net}.net.{i}.weight"] == (1024,)
        assert shapes[f"{net}.net.12.weight"] == (96, 1024)
    assert shapes["decoder.net.0.weight"] == (1024, 387)
    assert shapes["decoder.net.3.weight"] == (1024, 1072)
    assert shapes["decoder.net.6.weight"] == (512, 1072)
    assert shapes["decoder.net.9.weight"] == (216, 560)
    assert len(shapes) == 18 + 18 + 14  # (Linear w, b) x 5 + (GroupNorm w, b) x 4; decoder 4 + 3


def numpy_mlp(mlp, x, skip_dim=0):
    """Independent forward: Linear, then (GroupNorm(16) -> ReLU -> [h, skip] -> Linear) ..."""
    params = {k: v.detach().numpy() for k, v in mlp.state_dict().items()}
    skip = x[:, x.shape[1] - skip_dim:] if skip_dim else None
    linear_ids = sorted({int(k.split(".")[1]) for k in params if params[k].ndim == 2})
    h = x @ params[f"net.{linear_ids[0]}.weight"].T + params[f"net.{linear_ids[0]}.bias"]
    for lin in linear_ids[1:]:
        gn = lin - 2
        B, C = h.shape
        g = h.reshape(B, 16, C // 16)
        g = (g - g.mean(-1, keepdims=True)) / np.sqrt(g.var(-1, keepdims=True) + 1e-5)
        h = g.reshape(B, C) * params[f"net.{gn}.weight"] + params[f"net.{gn}.bias"]
        h = np.maximum(h, 0)
        if skip is not None:
            h = np.concatenate([h, skip], axis=1)
        h = h @ params[f"net.{lin}.weight"].T + params[f"net.{lin}.bias"]
    return h


def test_mlps_match_numpy_reference(model):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 678))
    np.testing.assert_allclose(model.encoder(torch.from_numpy(x)).detach().numpy(), numpy_mlp(model.encoder, x),
                               rtol=1e-10, atol=1e-12)
    x = rng.normal(size=(5, 339))
    np.testing.assert_allclose(model.prior_net(torch.from_numpy(x)).detach().numpy(),
                               numpy_mlp(model.prior_net, x), rtol=1e-10, atol=1e-12)
    x = rng.normal(size=(5, 387))
    np.testing.assert_allclose(model.decoder(torch.from_numpy(x)).detach().numpy(),
                               numpy_mlp(model.decoder, x, skip_dim=48), rtol=1e-10, atol=1e-12)


def test_gaussian_nll_matches_torch_distributions():
    g = torch.Generator().manual_seed(3)
    z, mean, logvar = (torch.randn(4, 48, generator=g, dtype=torch.float64) for _ in range(3))
    expected = -torch.distributions.Normal(mean, torch.exp(0.5 * logvar)).log_prob(z).sum(-1)
    torch.testing.assert_close(gaussian_nll(z, mean, logvar), expected, rtol=1e-12, atol=1e-12)


def test_transition_nll_is_nll_of_posterior_mean_under_prior(model):
    x = random_states(4, seed=1)
    x_prev, x_next = x[:2], x[2:]
    c_prev, c_next = hs.canonicalize_pair(x_prev, x_next)
    mu_q = model.encoder(torch.cat([c_prev, c_next], 1))[:, :48]
    prior = model.prior_net(c_prev)
    sigma = torch.exp(0.5 * prior[:, 48:])
    expected = (torch.log(sigma) + 0.5 * math.log(2 * math.pi) + (mu_q - prior[:, :48]) ** 2 / (2 * sigma**2)).sum(-1)
    torch.testing.assert_close(transition_nll(model, x_prev, x_next), expected, rtol=1e-12, atol=1e-10)
    # A latent NLL at the posterior mean is the same number.
    torch.testing.assert_close(latent_nll(model, mu_q, x_prev), expected, rtol=1e-12, atol=1e-10)
    seq = random_states(5, seed=2)
    torch.testing.assert_close(sequence_transition_nll(model, seq), transition_nll(model, seq[:-1], seq[1:]).sum())


def yaw(angle):
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64)


def move(x, Q, centre, shift, trans_as_point=False):
    """Rigid motion p -> Q (p - centre) + centre + shift (Q about +z) of states (n, 339), written out
    independently of humor_state. SMPL's translation is pelvis - j0 (j0 fixed by the shape) unless
    trans_as_point, where it moves like a point."""
    n = x.shape[0]
    out = x.clone()
    joints = x[:, hs.JOINTS].reshape(n, 22, 3)
    moved_joints = (joints - centre) @ Q.T + centre + shift
    out[:, hs.JOINTS] = moved_joints.reshape(n, 66)
    if trans_as_point:
        out[:, hs.TRANS] = (x[:, hs.TRANS] - centre) @ Q.T + centre + shift
    else:
        out[:, hs.TRANS] = moved_joints[:, 0] - (joints[:, 0] - x[:, hs.TRANS])
    for sl in (hs.TRANS_VEL, hs.ROOT_ORIENT_VEL):
        out[:, sl] = x[:, sl] @ Q.T
    out[:, hs.JOINTS_VEL] = (x[:, hs.JOINTS_VEL].reshape(n, 22, 3) @ Q.T).reshape(n, 66)
    out[:, hs.ROOT_ORIENT] = (Q @ x[:, hs.ROOT_ORIENT].reshape(n, 3, 3)).reshape(n, 9)
    return out


def test_terms_are_invariant_to_heading_and_horizontal_position(model):
    """The canonical frame removes heading and horizontal position: moving both states of a pair rigidly
    (a rotation about any vertical axis, a horizontal shift) leaves both terms unchanged."""
    x = random_states(2, seed=5)
    # One body: the rest pelvis j0 = joints[0] - trans is the same in both states.
    x[1, hs.TRANS] = x[1, hs.JOINTS][:3] - (x[0, hs.JOINTS][:3] - x[0, hs.TRANS])
    centre = torch.tensor([0.4, -0.3, 0.0], dtype=torch.float64)
    shift = torch.tensor([1.5, -2.0, 0.0], dtype=torch.float64)
    moved = move(x, yaw(0.7), centre, shift)
    torch.testing.assert_close(transition_nll(model, moved[:1], moved[1:]), transition_nll(model, x[:1], x[1:]),
                               rtol=1e-10, atol=1e-9)
    z = torch.randn(1, 48, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(latent_nll(model, z, moved[:1]), latent_nll(model, z, x[:1]), rtol=1e-10, atol=1e-9)
    # A different pitch is not removed: the term must change (the check above is not vacuous).
    tilted = x.clone()
    tilted[:1, hs.ROOT_ORIENT] = (axis_angle_to_matrix(torch.tensor([[0.3, 0.0, 0.0]], dtype=torch.float64))
                                  @ x[:1, hs.ROOT_ORIENT].reshape(1, 3, 3)).reshape(1, 9)
    assert abs(float(transition_nll(model, tilted[:1], tilted[1:]) - transition_nll(model, x[:1], x[1:]))) > 1e-6


def test_decode_world_is_equivariant_to_heading(model):
    x = random_states(1, seed=7)
    # With the translation over the pelvis, HuMoR's two pivots coincide and a roll-out step commutes with
    # any rigid motion about a vertical axis.
    x[:, 0:2] = x[:, hs.JOINTS.start:hs.JOINTS.start + 2]
    z = torch.randn(1, 48, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    Q = yaw(-1.1)
    centre = torch.tensor([0.2, 0.5, 0.0], dtype=torch.float64)
    shift = torch.tensor([-0.7, 0.1, 0.0], dtype=torch.float64)
    nxt, contacts = model.decode_world(x, z)
    nxt_moved, contacts_moved = model.decode_world(move(x, Q, centre, shift, trans_as_point=True), z)
    torch.testing.assert_close(nxt_moved, move(nxt, Q, centre, shift, trans_as_point=True), rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(contacts_moved, contacts, rtol=1e-10, atol=1e-10)


def test_decoder_with_zero_output_keeps_the_state():
    x = random_states(2, seed=9)
    nxt, contacts = hs.apply_decoder_output(x, torch.zeros(2, hs.DECODER_OUTPUT_DIM, dtype=torch.float64))
    torch.testing.assert_close(nxt, x, rtol=0, atol=1e-15)
    assert contacts.shape == (2, 9)


def save_official(model, path, prefix="module.", legacy=False, extra=None):
    state = {prefix + k: v.float() for k, v in model.state_dict().items()}
    payload = {"model": state, "optim": {"state": {}, "param_groups": []}, "epoch": 12, "min_val_loss": 0.5,
               "min_train_loss": 0.4}
    if extra:
        payload.update(extra)
    torch.save(payload, path, _use_new_zipfile_serialization=not legacy)


@pytest.mark.parametrize("prefix,legacy", [("module.", False), ("", False), ("module.", True)])
def test_loads_official_layout(model, tmp_path, prefix, legacy):
    path = tmp_path / "best_model.pth"
    save_official(model, path, prefix, legacy)
    loaded = load_humor(path, dtype=torch.float64)
    assert not loaded.training
    for k, v in model.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[k], v.float().double(), rtol=0, atol=0)
    x = random_states(3, seed=11)
    rounded = copy.deepcopy(model).float().double()  # the file holds float32, as the official one does
    torch.testing.assert_close(transition_nll(loaded, x[:2], x[1:]), transition_nll(rounded, x[:2], x[1:]),
                               rtol=1e-12, atol=1e-10)


def test_loads_from_models_folder(model, tmp_path, monkeypatch):
    (tmp_path / "humor").mkdir()
    save_official(model, tmp_path / "humor" / "best_model.pth")
    monkeypatch.setenv("M3C_MODELS", str(tmp_path))
    loaded = load_humor()
    torch.testing.assert_close(loaded.prior_net.net[0].weight, model.prior_net.net[0].weight.float())


def test_missing_file_names_path_and_source(tmp_path, monkeypatch):
    missing = tmp_path / "nope.pth"
    with pytest.raises(ckpt.CheckpointNotFoundError) as err:
        load_humor(missing)
    assert str(missing) in str(err.value)
    assert "download.cs.stanford.edu/orion/humor" in str(err.value)
    monkeypatch.delenv("M3C_MODELS", raising=False)
    with pytest.raises(ckpt.CheckpointNotFoundError, match="M3C_MODELS"):
        load_humor()


def test_mismatched_file_names_keys_and_shapes(model, tmp_path):
    state = {"module." + k: v.float() for k, v in model.state_dict().items()}
    del state["module.encoder.net.0.weight"]
    state["module.prior_net.net.0.weight"] = torch.zeros(1024, 338)
    state["module.extra.weight"] = torch.zeros(2)
    path = tmp_path / "bad.pth"
    torch.save({"model": state}, path)
    with pytest.raises(ckpt.CheckpointError) as err:
        load_humor(path)
    msg = str(err.value)
    assert str(path) in msg
    assert "encoder.net.0.weight (1024, 678)" in msg
    assert "prior_net.net.0.weight expected (1024, 339) got (1024, 338)" in msg
    assert "extra.weight" in msg
    assert "get_ckpt.sh" in msg


def test_not_a_checkpoint(tmp_path):
    path = tmp_path / "garbage.pth"
    path.write_bytes(b"not a torch file")
    with pytest.raises(ckpt.CheckpointError, match="garbage.pth"):
        load_humor(path)
    path = tmp_path / "list.pth"
    torch.save([1, 2, 3], path)
    with pytest.raises(ckpt.CheckpointError, match="no state dict"):
        load_humor(path)


class _Exploit:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch {self.target}",))


class _Config:
    def __init__(self):
        self.lr = 1e-3


def test_foreign_objects_in_checkpoint_are_refused(model, tmp_path):
    """A checkpoint that pickles anything besides tensors, containers and the official files' config containers
    is refused with the class it names, and code in it never runs."""
    marker = tmp_path / "ran"
    for extra, named in (({"hook": _Exploit(marker)}, "system"), ({"config": _Config()}, "_Config")):
        path = tmp_path / "with_objects.pth"
        save_official(model, path, extra=extra)
        with pytest.raises(ckpt.CheckpointError, match=f"refused.*{named}"):
            load_humor(path)
    assert not marker.exists()


def test_official_config_containers_in_checkpoint_load(model, tmp_path):
    """A config pickled as one of the official files' containers (here yacs' CfgNode) loads as a plain one."""
    cfg = named_class("yacs.config.CfgNode")
    path = tmp_path / "with_config.pth"
    with importable(cfg):
        save_official(model, path, extra={"config": cfg(lr=1e-3)})
    loaded = load_humor(path)
    torch.testing.assert_close(loaded.encoder.net[12].bias, model.encoder.net[12].bias.float())
