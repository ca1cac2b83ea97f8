"""The C++ runtime (cpp/nn) against the torch models on random weights exported in the official layout:
network outputs to 1e-9 relative in double, motion-prior gradients to 1e-7 relative against torch autograd,
the state builder and canonical frame against the torch implementation."""

import numpy as np
import pytest
import torch

from m3c.body.torch_lbs import TorchBodyModel, axis_angle_to_matrix
from m3c.models import humor_state as hs
from m3c.models.export import export_weights
from m3c.models.humor import HumorModel, latent_nll, sequence_transition_nll, transition_nll
from m3c.models.safetensors_io import write_safetensors
from m3c.models.vposer import VPoserV1, VPoserV2
from m3c.nn import HumorPrior, VPoser, build_humor_states, canonicalize, read_safetensors


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def randomise_norms(model):
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, (torch.nn.GroupNorm, torch.nn.BatchNorm1d)):
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.uniform_(-0.3, 0.3)
                m.running_var.uniform_(0.5, 2.0)
    return model.requires_grad_(False)


@pytest.fixture(scope="module")
def humor(tmp_path_factory):
    torch.manual_seed(0)
    model = randomise_norms(HumorModel().double().eval())
    out = tmp_path_factory.mktemp("humor")
    export_weights(out, humor=model, dtype="float64")
    return model, HumorPrior(out / "humor.safetensors")


def random_states(n, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, 339, generator=g, dtype=torch.float64) * 0.3
    x[:, hs.ROOT_ORIENT] = axis_angle_to_matrix(torch.randn(n, 3, generator=g, dtype=torch.float64)).reshape(n, 9)
    x[:, hs.POSE_BODY] = axis_angle_to_matrix(
        0.5 * torch.randn(n, 21, 3, generator=g, dtype=torch.float64)).reshape(n, 189)
    return x


def test_network_outputs_match_torch(humor):
    model, cpp = humor
    pairs = random_states(6, 1).reshape(3, 678)
    with torch.no_grad():
        assert rel(cpp.encoder_forward(pairs.numpy()), model.encoder(pairs).numpy()) < 1e-9
        states = random_states(4, 2)
        assert rel(cpp.prior_forward(states.numpy()), model.prior_net(states).numpy()) < 1e-9


def test_transition_gradients_match_autograd(humor):
    model, cpp = humor
    x = random_states(8, 3)
    prev = x[:4].clone().requires_grad_(True)
    nxt = x[4:].clone().requires_grad_(True)
    values_t = transition_nll(model, prev, nxt)
    values_t.sum().backward()
    values, grad_prev, grad_next = cpp.transition_nll(x[:4].numpy(), x[4:].numpy(), with_gradient=True)
    assert rel(values, values_t.detach().numpy()) < 1e-9
    assert rel(grad_prev, prev.grad.numpy()) < 1e-7
    assert rel(grad_next, nxt.grad.numpy()) < 1e-7
    # Values alone agree too (the path without the reverse pass).
    assert rel(cpp.transition_nll(x[:4].numpy(), x[4:].numpy()), values_t.detach().numpy()) < 1e-9
    with pytest.raises(ValueError, match=r"x_prev must have shape \(N, 339\), got \(2, 338\)"):
        cpp.transition_nll(np.zeros((2, 338)), np.zeros((2, 339)))
    with pytest.raises(ValueError, match=r"x_next must have shape \(2, 339\)"):
        cpp.transition_nll(np.zeros((2, 339)), np.zeros((3, 339)))


def test_latent_gradients_match_autograd(humor):
    model, cpp = humor
    prev = random_states(3, 4).requires_grad_(True)
    z = torch.randn(3, 48, dtype=torch.float64, generator=torch.Generator().manual_seed(5)).requires_grad_(True)
    values_t = latent_nll(model, z, prev)
    values_t.sum().backward()
    values, grad_prev, grad_z = cpp.latent_nll(prev.detach().numpy(), z.detach().numpy(), with_gradient=True)
    assert rel(values, values_t.detach().numpy()) < 1e-9
    assert rel(grad_prev, prev.grad.numpy()) < 1e-7
    assert rel(grad_z, z.grad.numpy()) < 1e-7


def test_sequence_gradient_matches_autograd(humor, synthetic_model_data):
    """A realistic sequence: states built from a smooth motion of the synthetic body."""
    model, cpp = humor
    T = 12
    t = torch.arange(T, dtype=torch.float64) / 30
    trans = torch.stack([0.5 * t, 0.1 * torch.sin(4 * t), 0.9 + 0.02 * t], 1)
    root = torch.stack([torch.full_like(t, 1.5), 0.1 * t, 0.3 * t], 1)
    g = torch.Generator().manual_seed(6)
    pose = 0.3 * torch.sin(2 * t[:, None, None] + torch.rand(21, 3, generator=g, dtype=torch.float64) * 6)
    body = TorchBodyModel(synthetic_model_data, dtype=torch.float64)
    states = hs.build_states_from_body(body, trans, root, pose, torch.zeros(10, dtype=torch.float64))
    states = states.detach().requires_grad_(True)
    total_t = sequence_transition_nll(model, states)
    total_t.backward()
    total, grad = cpp.sequence_transition_nll(states.detach().numpy())
    assert total == pytest.approx(total_t.item(), rel=1e-9)
    assert rel(grad, states.grad.numpy()) < 1e-7


def test_float32_export_matches_float32_weights(tmp_path):
    torch.manual_seed(1)
    model = randomise_norms(HumorModel().eval())  # float32, like the official checkpoint
    export_weights(tmp_path, humor=model)  # float32 on disk
    cpp = HumorPrior(tmp_path / "humor.safetensors")
    x = random_states(4, 7)
    expected = transition_nll(model.double(), x[:2], x[2:]).numpy()
    assert rel(cpp.transition_nll(x[:2].numpy(), x[2:].numpy()), expected) < 1e-9


def test_state_builder_matches_torch():
    rng = np.random.default_rng(8)
    T = 9
    trans = rng.normal(size=(T, 3))
    root = rng.normal(scale=0.8, size=(T, 3))
    pose = rng.normal(scale=0.4, size=(T, 21, 3))
    joints = rng.normal(size=(T, 24, 3))  # extra joints are ignored
    for ground in (None, hs.ground_from_plane(rng.normal(size=3), 0.4),
                   hs.ground_from_plane(rng.normal(size=(T, 3)), rng.normal(size=T))):
        expected = hs.build_states(trans, root, pose, joints, fps=25.0, ground_from_world=ground).numpy()
        got = build_humor_states(trans, root, pose, joints, fps=25.0,
                                 ground_from_world=None if ground is None else tuple(v.numpy() for v in ground))
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    x = random_states(5, 9)
    frames = random_states(5, 10)
    np.testing.assert_allclose(canonicalize(x.numpy(), frames.numpy()),
                               hs.to_canonical(x, hs.canonical_frame(frames)).numpy(), rtol=1e-13, atol=1e-14)
    with pytest.raises(ValueError, match=r"joints must have shape \(T=9, J >= 22, 3\)"):
        build_humor_states(trans, root, pose, joints[:, :20], fps=25.0)


@pytest.mark.parametrize("cls", [VPoserV1, VPoserV2])
def test_vposer_matches_torch(cls, tmp_path):
    torch.manual_seed(2)
    model = randomise_norms(cls().double().eval())
    export_weights(tmp_path, vposer=model, dtype="float64")
    cpp = VPoser(tmp_path / "vposer.safetensors")
    assert cpp.version == model.version and cpp.latent_dim == 32
    z = torch.randn(5, 32, dtype=torch.float64)
    pose = 0.4 * torch.randn(5, 21, 3, dtype=torch.float64)
    with torch.no_grad():
        assert rel(cpp.decode(z.numpy()), model.decode(z).numpy()) < 1e-9
        mean, scale = model.encode(pose)
    got_mean, got_scale = cpp.encode(pose.numpy())
    assert rel(got_mean, mean.numpy()) < 1e-9
    assert rel(got_scale, scale.numpy()) < 1e-9


def test_cpp_reader_reads_python_files(tmp_path):
    rng = np.random.default_rng(11)
    tensors = {"a": rng.normal(size=(3, 4)), "b": rng.normal(size=5).astype(np.float32),
               "c": np.arange(6, dtype=np.int64).reshape(2, 3), "d": rng.normal(size=2).astype(np.float16)}
    write_safetensors(tmp_path / "t.safetensors", tensors, {"k": "v"})
    got, meta = read_safetensors(tmp_path / "t.safetensors")
    assert meta == {"k": "v"}
    for k, v in tensors.items():
        assert got[k].dtype == np.float64 and got[k].shape == v.shape
        np.testing.assert_array_equal(got[k], v.astype(np.float64))
    with pytest.raises(FileNotFoundError, match="m3c.models.export"):
        HumorPrior(tmp_path / "missing.safetensors")
    with pytest.raises(ValueError, match="no M3C manifest entry"):
        HumorPrior(tmp_path / "t.safetensors")
