"""DPVO's networks: sizes from first principles, the official dpvo.pth layout (random weights saved as DPVO saves
them, then loaded), the correlation lookup against a numpy port of the CUDA kernel's two steps (integer window,
then bilinear blend), the soft aggregation and the temporal neighbours against loops, and the operator on two real
frames of the bundled clip."""

from pathlib import Path

import numpy as np
import pytest
import torch

from m3c.models import checkpoint as ckpt
from m3c.models.dpvo import (CORR_DIM, DPVONet, SoftAgg, correlation, load_dpvo, parameter_count, patch_features,
                             temporal_neighbors)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

CLIP = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"


def conv(i, o, k):
    return i * o * k * k + o


def lin(i, o):
    return i * o + o


def encoder(out):
    d = 32
    block = 2 * conv(d, d, 3)
    return (conv(3, d, 7) + 2 * block + conv(d, 2 * d, 3) + conv(2 * d, 2 * d, 3) + conv(d, 2 * d, 1)
            + 2 * conv(2 * d, 2 * d, 3) + conv(2 * d, out, 1))


def test_parameter_count_from_first_principles():
    D = 384
    update = (2 * (2 * lin(D, D)) + 2 * D + 2 * 3 * lin(D, D) + 2 * (2 * D) + 2 * 3 * lin(D, D)
              + lin(882, D) + lin(D, D) + 2 * D + lin(D, D) + 2 * lin(D, 2))
    model = DPVONet()
    assert parameter_count(model.update) == update
    assert parameter_count(model) == encoder(128) + encoder(384) + update == 3_384_324
    assert round(parameter_count(model) / 1e6, 1) == 3.4  # the thesis's Table 4.1


def test_official_key_layout():
    state = DPVONet().state_dict()
    for key, shape in {"patchify.fnet.conv1.weight": (32, 3, 7, 7), "patchify.fnet.layer2.0.downsample.0.weight":
                       (64, 32, 1, 1), "patchify.inet.conv2.weight": (384, 64, 1, 1),
                       "update.corr.0.weight": (384, 882), "update.corr.3.weight": (384,),
                       "update.gru.1.gate.0.weight": (384, 384), "update.gru.3.res.2.bias": (384,),
                       "update.agg_ij.h.weight": (384, 384), "update.c2.2.weight": (384, 384),
                       "update.d.1.weight": (2, 384), "update.w.1.bias": (2,)}.items():
        assert tuple(state[key].shape) == shape, key
    assert not any("norm" in k for k in state if k.startswith("patchify"))  # instance norm: no parameters
    assert len(state) == 94


@pytest.fixture(scope="module")
def dpvo_file(tmp_path_factory):
    torch.manual_seed(0)
    model = DPVONet().eval()
    path = tmp_path_factory.mktemp("dpvo") / "dpvo.pth"
    state = {"module." + k: v for k, v in model.state_dict().items()}
    state["module.update.lmbda"] = torch.tensor([1e-3])
    torch.save(state, path)
    return path, model


def test_loads_official_file_and_reports_problems(dpvo_file, tmp_path):
    path, model = dpvo_file
    loaded = load_dpvo(path)
    for key, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key
    with pytest.raises(ckpt.CheckpointNotFoundError, match="DPVO.*princeton-vl/DPVO"):
        load_dpvo(tmp_path / "dpvo.pth")
    torch.save({k: v for k, v in torch.load(path).items() if "update.w" not in k}, tmp_path / "cut.pth")
    with pytest.raises(ckpt.CheckpointError, match=r"missing keys update\.w\.1\.weight \(2, 384\)"):
        load_dpvo(tmp_path / "cut.pth")


def kernel_reference(gmap, fmaps, coords, radius=3, levels=(1, 4)):
    """The CUDA kernel's two steps in numpy: dot products on the (2R+2)^2 integer window from floor(coords)
    (zero outside the map), then the bilinear blend of neighbouring window entries; DPVO's output order."""
    E, C, P, _ = gmap.shape
    D = 2 * radius + 2
    out = []
    for level in levels:
        level_out = np.zeros((E, 2 * radius + 1, 2 * radius + 1, P, P))  # (x offset, y offset, row, col)
        for e in range(E):
            f = fmaps[e]
            if level > 1:
                h, w = f.shape[1] // level, f.shape[2] // level
                f = f[:, :h * level, :w * level].reshape(C, h, level, w, level).mean(axis=(2, 4))
            H, W = f.shape[1:]
            for r in range(P):
                for c in range(P):
                    x, y = coords[e, r, c] / level
                    corr = np.zeros((D, D))
                    for a in range(D):
                        for b in range(D):
                            i1, j1 = int(np.floor(y)) + a - radius, int(np.floor(x)) + b - radius
                            if 0 <= i1 < H and 0 <= j1 < W:
                                corr[a, b] = gmap[e, :, r, c] @ f[:, i1, j1]
                    dx, dy = x - np.floor(x), y - np.floor(y)
                    blend = ((1 - dx) * (1 - dy) * corr[:-1, :-1] + dx * (1 - dy) * corr[:-1, 1:]
                             + (1 - dx) * dy * corr[1:, :-1] + dx * dy * corr[1:, 1:])
                    level_out[e, :, :, r, c] = blend.T
        out.append(level_out)
    return np.stack(out, axis=-1).reshape(E, -1)


def test_correlation_matches_the_kernel():
    rng = np.random.default_rng(0)
    E, C = 3, 8
    gmap = rng.normal(size=(E, C, 3, 3))
    fmaps = rng.normal(size=(E, C, 20, 24))
    coords = np.stack([rng.uniform(-2, 26, (E, 3, 3)), rng.uniform(-2, 22, (E, 3, 3))], axis=-1)  # some outside
    got = correlation(torch.from_numpy(gmap), torch.from_numpy(fmaps), torch.from_numpy(coords))
    assert got.shape == (E, CORR_DIM)
    np.testing.assert_allclose(got.numpy(), kernel_reference(gmap, fmaps, coords), atol=1e-10)
    # One target map for every edge (the VO's case) takes the batched path.
    shared = correlation(torch.from_numpy(gmap), torch.from_numpy(fmaps[1]), torch.from_numpy(coords))
    np.testing.assert_allclose(shared.numpy(), kernel_reference(gmap, fmaps[[1, 1, 1]], coords), atol=1e-10)


def test_patch_features_at_integer_centres_are_the_pixels():
    rng = np.random.default_rng(1)
    fmap, imap = torch.from_numpy(rng.normal(size=(128, 10, 12))), torch.from_numpy(rng.normal(size=(384, 10, 12)))
    g, i = patch_features(fmap, imap, torch.tensor([[4.0, 5.0], [1.0, 1.0]], dtype=torch.float64))
    np.testing.assert_array_equal(g[0].numpy(), fmap[:, 4:7, 3:6].numpy())
    np.testing.assert_array_equal(i[1].numpy(), imap[:, 1, 1].numpy())


def test_temporal_neighbors_and_soft_aggregation():
    kk = torch.tensor([5, 2, 5, 5, 2])
    jj = torch.tensor([7, 3, 4, 9, 1])
    prev, nxt = temporal_neighbors(kk, jj)
    # patch 5: edges 2 (j=4) < 0 (j=7) < 3 (j=9); patch 2: edges 4 (j=1) < 1 (j=3)
    assert prev.tolist() == [2, 4, -1, 0, -1] and nxt.tolist() == [3, -1, 0, -1, 1]
    torch.manual_seed(0)
    agg = SoftAgg(6).double()
    x = torch.randn(1, 5, 6, dtype=torch.float64)
    got = agg(x, kk)[0]
    f, g = agg.f(x[0]).detach().numpy(), agg.g(x[0]).detach().numpy()
    for e in range(5):
        members = (kk == kk[e]).numpy()
        w = np.exp(g[members] - g[members].max(axis=0))
        w /= w.sum(axis=0)
        expected = agg.h(torch.from_numpy((w * f[members]).sum(axis=0))).detach().numpy()
        np.testing.assert_allclose(got[e].detach().numpy(), expected, atol=1e-12)


def test_update_operator_on_two_real_frames(dpvo_file):
    import cv2

    _, model = dpvo_file
    cap = cv2.VideoCapture(str(CLIP))
    frames = []
    for _ in range(2):
        ok, frame = cap.read()
        assert ok
        frames.append(cv2.resize(frame, (240, 136), interpolation=cv2.INTER_AREA))  # BGR, sides multiples of 4
    cap.release()
    fmap, imap = model.encode(torch.from_numpy(np.stack(frames)))
    assert fmap.shape == (2, 128, 34, 60) and imap.shape == (2, 384, 34, 60)
    centres = torch.tensor([[10.0, 8.0], [30.0, 20.0], [50.0, 12.0], [5.0, 30.0]])
    gmap, context = patch_features(fmap[0], imap[0], centres)
    grid = torch.stack(torch.meshgrid(torch.arange(-1.0, 2.0), torch.arange(-1.0, 2.0), indexing="ij")[::-1], -1)
    coords = centres[:, None, None] + grid  # the patches where they were (no motion yet)
    corr = correlation(gmap, fmap[1], coords)
    kk = torch.arange(4)
    with torch.no_grad():
        net, delta, weight = model.update(torch.zeros(1, 4, 384), context[None], corr[None], torch.zeros(4).long(),
                                          torch.ones(4).long(), kk)
    assert net.shape == (1, 4, 384) and delta.shape == (1, 4, 2) and weight.shape == (1, 4, 2)
    assert torch.isfinite(delta).all() and ((weight > 0) & (weight < 1)).all()
