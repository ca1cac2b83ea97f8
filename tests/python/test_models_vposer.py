"""VPoser v1 and v2: parameter counts and key layouts (REFERENCE C), official file formats, and the networks
against an independent numpy implementation."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m3c.models import checkpoint as ckpt
from m3c.models.vposer import VPoserV1, VPoserV2, load_vposer
from pickled_names import importable, named_class


def randomised(model_cls, seed):
    torch.manual_seed(seed)
    m = model_cls().double().eval()
    with torch.no_grad():
        for module in m.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
                module.running_mean.uniform_(-0.3, 0.3)
                module.running_var.uniform_(0.5, 2.0)
    return m.requires_grad_(False)


def test_parameter_counts_match_reference():
    assert sum(p.numel() for p in VPoserV1().parameters()) == 673_596
    assert sum(p.numel() for p in VPoserV2().parameters()) == 936_252


def test_key_layouts():
    v1 = {k: tuple(v.shape) for k, v in VPoserV1().state_dict().items()}
    assert v1["bodyprior_enc_bn1.running_mean"] == (63,)
    assert v1["bodyprior_enc_fc1.weight"] == (512, 63)
    assert v1["bodyprior_enc_mu.weight"] == (32, 512)
    assert v1["bodyprior_enc_logvar.weight"] == (32, 512)
    assert v1["bodyprior_dec_fc1.weight"] == (512, 32)
    assert v1["bodyprior_dec_out.weight"] == (126, 512)
    assert all(k.startswith(("bodyprior_enc_", "bodyprior_dec_")) for k in v1)
    v2 = {k: tuple(v.shape) for k, v in VPoserV2().state_dict().items()}
    assert v2["encoder_net.1.running_var"] == (63,)
    assert v2["encoder_net.2.weight"] == (512, 63)
    assert v2["encoder_net.4.weight"] == (512,)
    assert v2["encoder_net.6.weight"] == (512, 512)
    assert v2["encoder_net.7.weight"] == (512, 512)
    assert v2["encoder_net.8.mu.weight"] == (32, 512)
    assert v2["encoder_net.8.logvar.bias"] == (32,)
    assert v2["decoder_net.0.weight"] == (512, 32)
    assert v2["decoder_net.3.weight"] == (512, 512)
    assert v2["decoder_net.5.weight"] == (126, 512)


def np_leaky(x, slope):
    return np.where(x > 0, x, slope * x)


def np_bn(x, p, name):
    return (x - p[name + ".running_mean"]) / np.sqrt(p[name + ".running_var"] + 1e-5) * p[name + ".weight"] + \
        p[name + ".bias"]


def np_lin(x, p, name):
    return x @ p[name + ".weight"].T + p[name + ".bias"]


def np_softplus(x):
    return np.log1p(np.exp(x))


def np_6d_columns(x):
    """Gram-Schmidt on the two columns of each 3x2 block (VPoser's convention)."""
    m = x.reshape(-1, 3, 2)
    a, b = m[:, :, 0], m[:, :, 1]
    b1 = a / np.linalg.norm(a, axis=1, keepdims=True)
    b2 = b - np.sum(b1 * b, axis=1, keepdims=True) * b1
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    return np.stack([b1, b2, np.cross(b1, b2)], axis=-1)


def reference_v1(m, pose, z):
    p = {k: v.numpy() for k, v in m.state_dict().items()}
    h = np_bn(pose.reshape(len(pose), 63), p, "bodyprior_enc_bn1")
    h = np_bn(np_leaky(np_lin(h, p, "bodyprior_enc_fc1"), 0.2), p, "bodyprior_enc_bn2")
    h = np_leaky(np_lin(h, p, "bodyprior_enc_fc2"), 0.2)
    mean, scale = np_lin(h, p, "bodyprior_enc_mu"), np_softplus(np_lin(h, p, "bodyprior_enc_logvar"))
    d = np_leaky(np_lin(z, p, "bodyprior_dec_fc1"), 0.2)
    d = np_leaky(np_lin(d, p, "bodyprior_dec_fc2"), 0.2)
    rot = np_6d_columns(np_lin(d, p, "bodyprior_dec_out")).reshape(len(z), 21, 3, 3)
    return mean, scale, rot


def reference_v2(m, pose, z):
    p = {k: v.numpy() for k, v in m.state_dict().items()}
    h = np_bn(pose.reshape(len(pose), 63), p, "encoder_net.1")
    h = np_bn(np_leaky(np_lin(h, p, "encoder_net.2"), 0.01), p, "encoder_net.4")
    h = np_lin(np_lin(h, p, "encoder_net.6"), p, "encoder_net.7")
    mean, scale = np_lin(h, p, "encoder_net.8.mu"), np_softplus(np_lin(h, p, "encoder_net.8.logvar"))
    d = np_leaky(np_lin(z, p, "decoder_net.0"), 0.01)
    d = np_leaky(np_lin(d, p, "decoder_net.3"), 0.01)
    rot = np_6d_columns(np_lin(d, p, "decoder_net.5")).reshape(len(z), 21, 3, 3)
    return mean, scale, rot


@pytest.mark.parametrize("cls,reference", [(VPoserV1, reference_v1), (VPoserV2, reference_v2)])
def test_networks_match_numpy_reference(cls, reference):
    m = randomised(cls, seed=1)
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.4, size=(6, 21, 3))
    z = rng.normal(size=(6, 32))
    mean, scale = m.encode(torch.from_numpy(pose))
    rot = m.decode(torch.from_numpy(z))
    ref_mean, ref_scale, ref_rot = reference(m, pose, z)
    np.testing.assert_allclose(mean.numpy(), ref_mean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(scale.numpy(), ref_scale, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(rot.numpy(), ref_rot, rtol=1e-10, atol=1e-12)
    # Decoded matrices are rotations; their axis-angle decodes back to them.
    R = rot.numpy()
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    aa = m.decode_axis_angle(torch.from_numpy(z))
    np.testing.assert_allclose(Rotation.from_rotvec(aa.numpy().reshape(-1, 3)).as_matrix().reshape(R.shape), R,
                               atol=1e-10)


def save_v1(m, path, legacy=False, with_counter=True):
    state = {k: v.float() for k, v in m.state_dict().items() if with_counter or "num_batches" not in k}
    torch.save(state, path, _use_new_zipfile_serialization=not legacy)


# Lightning's hyper-parameter container, by the name the official files pickle it under.
HParams = named_class("pytorch_lightning.utilities.parsing.AttributeDict")


def save_v2(m, path):
    state = {"vp_model." + k: v.float() for k, v in m.state_dict().items()}
    state["vp_model.bm_train.v_template"] = torch.zeros(10, 3)  # training body model, not VPoser's
    with importable(HParams):
        torch.save({"epoch": 13, "global_step": 1000, "pytorch-lightning_version": "1.2.0", "state_dict": state,
                    "hyper_parameters": HParams(latentD=32)}, path)


@pytest.mark.parametrize("legacy,with_counter", [(False, True), (True, False)])
def test_load_v1_snapshot(tmp_path, legacy, with_counter):
    m = randomised(VPoserV1, seed=2)
    snap = tmp_path / "vposer_v1_0" / "snapshots"
    snap.mkdir(parents=True)
    save_v1(m, snap / "TR00_E096.pt", legacy, with_counter)
    for path in (snap / "TR00_E096.pt", tmp_path / "vposer_v1_0"):
        loaded = load_vposer(path, dtype=torch.float64)
        assert isinstance(loaded, VPoserV1) and not loaded.training
        z = torch.randn(3, 32, dtype=torch.float64)
        torch.testing.assert_close(loaded.decode(z), m.float().double().decode(z), rtol=1e-12, atol=1e-12)


def test_load_v2_lightning_checkpoint(tmp_path, monkeypatch):
    m = randomised(VPoserV2, seed=3)
    snap = tmp_path / "V02_05" / "snapshots"
    snap.mkdir(parents=True)
    save_v2(m, snap / "V02_05_epoch=13_val_loss=0.03.ckpt")
    loaded = load_vposer(tmp_path / "V02_05", dtype=torch.float64)
    assert isinstance(loaded, VPoserV2)
    pose = torch.randn(4, 63, dtype=torch.float64) * 0.3
    ref = m.float().double()
    for a, b in zip(loaded.encode(pose), ref.encode(pose)):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    monkeypatch.setenv("M3C_MODELS", str(tmp_path))
    assert isinstance(load_vposer(version="v2"), VPoserV2)


def test_errors_name_file_keys_and_source(tmp_path, monkeypatch):
    with pytest.raises(ckpt.CheckpointNotFoundError) as err:
        load_vposer(tmp_path / "missing.pt")
    assert "missing.pt" in str(err.value) and "smpl-x.is.tue.mpg.de" in str(err.value)
    monkeypatch.setenv("M3C_MODELS", str(tmp_path))
    with pytest.raises(ckpt.CheckpointNotFoundError, match="vposer_v1_0"):
        load_vposer()
    (tmp_path / "empty" / "snapshots").mkdir(parents=True)
    with pytest.raises(ckpt.CheckpointNotFoundError, match=r"no file matching \*\.pt"):
        load_vposer(tmp_path / "empty")
    # A v2 file read as v1: every v1 key is reported missing, with its shape.
    m = randomised(VPoserV2, seed=4)
    save_v2(m, tmp_path / "v2.ckpt")
    with pytest.raises(ckpt.CheckpointError) as err:
        load_vposer(tmp_path / "v2.ckpt", version="v1")
    assert "bodyprior_enc_fc1.weight (512, 63)" in str(err.value)
    # A v1 file whose decoder has the wrong width.
    state = {k: v.float() for k, v in VPoserV1().state_dict().items()}
    state["bodyprior_dec_out.weight"] = torch.zeros(120, 512)
    torch.save(state, tmp_path / "bad.pt")
    with pytest.raises(ckpt.CheckpointError, match=r"bodyprior_dec_out.weight expected \(126, 512\) got \(120, 512\)"):
        load_vposer(tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="version"):
        load_vposer(tmp_path / "bad.pt", version="v3")
