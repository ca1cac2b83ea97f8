"""WHAM's modules: architecture sizes from first principles, the recurrent wiring against a numpy LSTM, the
helper functions against closed forms, and loading the official checkpoint layout."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m3c.models import checkpoint as ckpt
from m3c.models.wham import (CONTEXT_DIM, Integrator, WhamLifter, camera_angular_velocity, keypoint_inputs,
                             load_wham, rollout_global_motion)


@pytest.fixture(scope="module")
def wham():
    torch.manual_seed(0)
    model = WhamLifter().double().eval().requires_grad_(False)
    with torch.no_grad():
        model.mask_embedding.normal_()
        # WHAM initialises its heads with gain 0.01; larger random heads make the recurrences visible.
        for name, p in model.named_parameters():
            if "declayer" in name:
                p.normal_(0, 0.2)
    return model


def lstm_params(inp, hidden, layers):
    return sum(4 * hidden * ((inp if layer == 0 else hidden) + hidden) + 8 * hidden for layer in range(layers))


def linear_params(inp, out):
    return inp * out + out


def test_parameter_counts_from_first_principles(wham):
    counts = {name: sum(p.numel() for p in m.parameters()) for name, m in wham.named_children()}
    assert counts["motion_encoder"] == (linear_params(37, 512) + linear_params(88, 512) + linear_params(512, 1536)
                                        + linear_params(1536, 3072) + lstm_params(563, 512, 3)
                                        + linear_params(512, 51))
    assert counts["trajectory_decoder"] == lstm_params(575, 563, 3) + linear_params(563, 3) + linear_params(563, 6)
    assert counts["integrator"] == linear_params(1587, 1024) + linear_params(1024, 1024) + linear_params(1024, 563)
    assert counts["motion_decoder"] == (linear_params(120, 563) + linear_params(563, 1689)
                                        + linear_params(1689, 3378) + lstm_params(707, 563, 3)
                                        + sum(linear_params(563, o) for o in (144, 10, 3, 4)))
    assert counts["trajectory_refiner"] == lstm_params(584, 512, 2) + linear_params(512, 6) + linear_params(512, 3)
    assert sum(p.numel() for p in wham.parameters()) == 42_034_668
    keys = wham.state_dict()
    assert keys["trajectory_refiner.refiner.rnn.weight_ih_l0"].shape == (4 * 512, 584)
    assert keys["motion_encoder.regressor.declayer0.weight"].shape == (51, 512)
    assert keys["mask_embedding"].shape == (1, 1, 17, 2)


def np_lstm_step(params, prefix, layers, x, state):
    """One step of a stacked LSTM in numpy (gates i, f, g, o)."""
    h, c = state
    sig = lambda v: 1 / (1 + np.exp(-v))  # noqa: E731
    new_h, new_c = [], []
    inp = x
    for layer in range(layers):
        p = {k: params[f"{prefix}.{k}_l{layer}"] for k in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")}
        gates = p["weight_ih"] @ inp + p["bias_ih"] + p["weight_hh"] @ h[layer] + p["bias_hh"]
        i, f, g, o = np.split(gates, 4)
        cell = sig(f) * c[layer] + sig(i) * np.tanh(g)
        out = sig(o) * np.tanh(cell)
        new_h.append(out)
        new_c.append(cell)
        inp = out
    return inp, (new_h, new_c)


def np_linear(params, prefix, x):
    return params[prefix + ".weight"] @ x + params[prefix + ".bias"]


def test_motion_encoder_and_trajectory_decoder_match_numpy(wham):
    rng = np.random.default_rng(1)
    F = 4
    x = rng.normal(size=(1, F, 37))
    init_kp = rng.normal(size=(1, 1, 88))
    init_root = rng.normal(size=(1, 1, 6))
    cam = rng.normal(scale=0.1, size=(1, F, 6))
    kp, context = wham.motion_encoder(torch.from_numpy(x), torch.from_numpy(init_kp))
    roots, vels = wham.trajectory_decoder(context, torch.from_numpy(init_root), torch.from_numpy(cam))

    p = {k: v.numpy() for k, v in wham.state_dict().items()}
    relu = lambda v: np.maximum(v, 0)  # noqa: E731
    init = np_linear(p, "motion_encoder.neural_init.linear3", relu(np_linear(
        p, "motion_encoder.neural_init.linear2", relu(np_linear(p, "motion_encoder.neural_init.linear1",
                                                                init_kp[0, 0])))))
    init = init.reshape(2, 3, 512)
    state = ([init[0, layer] for layer in range(3)], [init[1, layer] for layer in range(3)])
    previous = init_kp[0, 0, :51]
    ref_context = []
    for t in range(F):
        e = np_linear(p, "motion_encoder.embed_layer", x[0, t])
        h, state = np_lstm_step(p, "motion_encoder.regressor.rnn", 3, np.concatenate([e, previous]), state)
        previous = np_linear(p, "motion_encoder.regressor.declayer0", h)
        ref_context.append(np.concatenate([h, previous]))
    ref_context = np.array(ref_context)
    np.testing.assert_allclose(context[0].numpy(), ref_context, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(kp[0].reshape(F, 51).numpy(), ref_context[:, 512:], rtol=1e-10, atol=1e-12)

    state = ([np.zeros(563)] * 3, [np.zeros(563)] * 3)
    root = init_root[0, 0]
    for t in range(F):
        h, state = np_lstm_step(p, "trajectory_decoder.regressor.rnn", 3,
                                np.concatenate([ref_context[t], root, cam[0, t]]), state)
        vel = np_linear(p, "trajectory_decoder.regressor.declayer0", h)
        root = np_linear(p, "trajectory_decoder.regressor.declayer1", h)
        np.testing.assert_allclose(vels[0, t].numpy(), vel, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(roots[0, t + 1].numpy(), root, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(roots[0, 0].numpy(), init_root[0, 0])


def test_lift_is_causal_and_masks_keypoints(wham):
    g = torch.Generator().manual_seed(2)
    F = 6
    x = torch.randn(1, F, 37, generator=g, dtype=torch.float64)
    mask = torch.zeros(1, F, 17, dtype=torch.bool)
    mask[0, 2, 5] = True
    args = (torch.randn(1, 1, 88, generator=g, dtype=torch.float64),
            torch.tensor([[[1.0, 0, 0, 0, 1, 0]]], dtype=torch.float64),
            0.1 * torch.randn(1, F, 6, generator=g, dtype=torch.float64))
    out = wham.lift(x, mask, *args)
    assert out["trans_world"].shape == (1, F, 3) and out["root_world"].shape == (1, F, 3, 3)
    changed = x.clone()
    changed[0, 4] += 1.0  # a later frame cannot change earlier outputs
    out2 = wham.lift(changed, mask, *args)
    torch.testing.assert_close(out2["context"][:, :4], out["context"][:, :4], rtol=0, atol=0)
    assert not torch.allclose(out2["context"][:, 4:], out["context"][:, 4:])
    masked = x.clone()
    masked[0, 2, 10:12] = 123.0  # keypoint 5 of frame 2 is masked: its values are not read
    torch.testing.assert_close(wham.lift(masked, mask, *args)["context"], out["context"], rtol=0, atol=0)
    xin = wham.masked_input(x, mask)
    torch.testing.assert_close(xin[0, 2, 10:12], wham.mask_embedding[0, 0, 5])
    torch.testing.assert_close(xin[0, 1], x[0, 1])


def test_refiner_corrects_the_trajectory(wham):
    g = torch.Generator().manual_seed(3)
    F = 5
    lifted = wham.lift(torch.randn(1, F, 37, generator=g, dtype=torch.float64), torch.zeros(1, F, 17, dtype=bool),
                       torch.randn(1, 1, 88, generator=g, dtype=torch.float64),
                       torch.tensor([[[1.0, 0, 0, 0, 1, 0]]], dtype=torch.float64),
                       torch.zeros(1, F, 6, dtype=torch.float64))
    feet = torch.randn(1, F, 4, 3, generator=g, dtype=torch.float64)
    contact = torch.rand(1, F, 4, generator=g, dtype=torch.float64)
    refined = wham.refine(lifted, feet, contact)
    torch.testing.assert_close(refined["root_6d"][:, 0], lifted["root_6d"][:, 0])
    assert not torch.allclose(refined["velocity"], lifted["velocity"])
    # The refiner reads foot velocities only where in contact: with no contact, moving the feet changes nothing.
    none = torch.zeros_like(contact)
    a = wham.refine(lifted, feet, none)
    b = wham.refine(lifted, feet + torch.randn(1, F, 4, 3, generator=g, dtype=torch.float64), none)
    torch.testing.assert_close(a["trans_world"], b["trans_world"], rtol=0, atol=0)


def test_integrator_residual_rule():
    torch.manual_seed(4)
    integ = Integrator().double().eval()
    context = torch.randn(2, 3, CONTEXT_DIM, dtype=torch.float64)
    features = torch.randn(2, 3, 1024, dtype=torch.float64)
    features[1, 2] = 0  # a frame without features switches the residual off for that sequence
    out = integ(context, features)
    with torch.no_grad():
        mlp = integ.layer3(torch.relu(integ.layer2(torch.relu(integ.layer1(torch.cat([context, features], -1))))))
    torch.testing.assert_close(out[0], mlp[0] + context[0])
    torch.testing.assert_close(out[1], mlp[1])


def test_rollout_matches_loop():
    rng = np.random.default_rng(5)
    rots = Rotation.random(5, random_state=6).as_matrix()
    root_6d = torch.from_numpy(rots[:, :2, :].reshape(1, 5, 6))
    vel = rng.normal(size=(1, 4, 3))
    R, trans = rollout_global_motion(root_6d, torch.from_numpy(vel))
    expected, position = [], np.zeros(3)
    for t in range(4):
        position = position + rots[t] @ vel[0, t]
        expected.append(position)
    np.testing.assert_allclose(trans[0].numpy(), np.array(expected), atol=1e-12)
    np.testing.assert_allclose(R[0].numpy(), rots[1:], atol=1e-12)


def test_camera_angular_velocity_closed_form():
    fps, rate = 30.0, 0.9  # rad/s about the camera's y axis
    R = Rotation.from_rotvec(np.outer(np.arange(5) * rate / fps, [0, 1, 0])).as_matrix()
    w = camera_angular_velocity(torch.from_numpy(R), fps).numpy()
    a = -rate / fps  # R[t-1] R[t]^T is a rotation by -rate/fps about y
    step = Rotation.from_rotvec([0, a, 0]).as_matrix()[:2].reshape(6)
    expected = (step - np.array([1, 0, 0, 0, 1, 0])) * fps
    np.testing.assert_allclose(w, np.tile(expected, (5, 1)), atol=1e-12)
    with pytest.raises(ValueError, match="cam_from_world_R"):
        camera_angular_velocity(torch.eye(3)[None], fps)


def test_keypoint_inputs():
    box = np.array([[960.0, 540.0, 400.0]])
    kp = np.tile(np.array([960.0, 540.0]), (1, 17, 1))
    kp[0, 1] = [1160.0, 340.0]  # box corner: (+1, -1)
    conf = np.full((1, 17), 0.9)
    conf[0, 3] = 0.2
    x, mask = keypoint_inputs(kp, conf, box, (1920, 1080))
    assert x.shape == (1, 37)
    np.testing.assert_allclose(x[0, :2].numpy(), [0, 0])
    np.testing.assert_allclose(x[0, 2:4].numpy(), [1, -1])
    np.testing.assert_allclose(x[0, 34:].numpy(), [0, 0, 400 / 1920])  # image centre -> (0, 0)
    assert mask[0].nonzero().flatten().tolist() == [3]


def test_load_official_layout(wham, tmp_path, monkeypatch):
    state = {k: v.float() for k, v in wham.state_dict().items()}
    state["smpl.body_pose"] = torch.zeros(1, 69)  # WHAM's checkpoint carries SMPL buffers; ignored
    path = tmp_path / "wham_vit_w_3dpw.pth.tar"
    torch.save({"model": state, "epoch": 30, "performance": 1.0}, path)
    loaded = load_wham(path, dtype=torch.float64)
    torch.testing.assert_close(loaded.trajectory_refiner.refiner.declayer1.weight,
                               wham.trajectory_refiner.refiner.declayer1.weight.float().double())
    (tmp_path / "wham").mkdir()
    path.rename(tmp_path / "wham" / path.name)
    monkeypatch.setenv("M3C_MODELS", str(tmp_path))
    assert isinstance(load_wham(), WhamLifter)
    # The ResNet variant (2048-d image features) is recognised from the integrator's width.
    resnet = WhamLifter(image_feature_dim=2048)
    torch.save({"model": resnet.state_dict()}, tmp_path / "resnet.pth.tar")
    assert load_wham(tmp_path / "resnet.pth.tar").integrator.layer1.in_features == 2048 + CONTEXT_DIM


def test_load_errors(wham, tmp_path):
    with pytest.raises(ckpt.CheckpointNotFoundError, match="fetch_demo_data.sh"):
        load_wham(tmp_path / "none.pth.tar")
    state = {k: v for k, v in wham.state_dict().items() if not k.startswith("trajectory_refiner.")}
    torch.save({"model": state}, tmp_path / "partial.pth.tar")
    with pytest.raises(ckpt.CheckpointError, match=r"trajectory_refiner.refiner.rnn.weight_ih_l0 \(2048, 584\)"):
        load_wham(tmp_path / "partial.pth.tar")
