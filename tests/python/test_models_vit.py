"""ViTPose and HMR 2.0 on the shared ViT: sizes from first principles (full sizes on torch's meta device, nothing
allocated), the official checkpoint layouts (random weights saved as the originals save them, then loaded), the
heatmap decoding against ground truth and an independent numpy reference, the 6D convention against scipy, the
crop camera against HMR 2.0's own projection, and a real frame of the bundled clip."""

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy.spatial.transform import Rotation

from m3c.models import checkpoint as ckpt
from m3c.models.hmr2 import FOCAL_LENGTH, HMR2, DecoderConfig, load_hmr2
from m3c.models.vit import ViT, ViTConfig, normalize_images, parameter_count
from m3c.models.vitpose import (COCO_FLIP_PAIRS, InputGeometry, ViTPose, decode_heatmaps, flip_back,
                                heatmap_to_frame, load_vitpose)
from m3c.perception.boxes import crop_to_full_camera, network_input
from pickled_names import importable, named_class

pytestmark = pytest.mark.usefixtures("one_torch_thread")

CLIP = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
SMALL_VIT = ViTConfig(embed_dim=64, depth=2, num_heads=4)
SMALL_DECODER = DecoderConfig(dim=32, depth=2, heads=2, dim_head=16, mlp_dim=48, context_dim=64)


def vit_params(C, depth, hidden_ratio=4):
    h = hidden_ratio * C
    block = 4 * C + (3 * C * C + 3 * C) + (C * C + C) + (C * h + h) + (h * C + C)
    return 3 * 16 * 16 * C + C + 193 * C + depth * block + 2 * C


def head_params(C, k=17):
    return C * 256 * 16 + 2 * 256 + 256 * 256 * 16 + 2 * 256 + 256 * k + k


def decoder_params(dim, depth, heads, dim_head, mlp, context):
    inner = heads * dim_head
    layer = (2 * dim + 3 * dim * inner + inner * dim + dim) + (2 * dim + context * 2 * inner + dim * inner
                                                                + inner * dim + dim) + (2 * dim + dim * mlp + mlp
                                                                                        + mlp * dim + dim)
    return (dim + dim) + dim + depth * layer + (dim * 144 + 144) + (dim * 10 + 10) + (dim * 3 + 3)


@pytest.mark.parametrize("size,expected", [("base", 89_994_513), ("large", 308_544_785), ("huge", 637_208_849)])
def test_vitpose_full_sizes(size, expected):
    with torch.device("meta"):
        model = ViTPose(ViTConfig.size(size))
    c = ViTConfig.size(size)
    assert parameter_count(model) == vit_params(c.embed_dim, c.depth) + head_params(c.embed_dim) == expected
    if size == "large":
        assert round(expected / 1e6, 1) == 308.5  # the thesis's Table 4.1 figure for its ViTPose


def test_hmr2_full_size():
    with torch.device("meta"):
        model = HMR2()
    d = DecoderConfig()
    assert parameter_count(model.smpl_head) == decoder_params(d.dim, d.depth, d.heads, d.dim_head, d.mlp_dim, 1280)
    assert parameter_count(model) == vit_params(1280, 32) + parameter_count(model.smpl_head) == 670_459_037
    assert round(parameter_count(model) / 1e6, 1) == 670.5  # thesis Table 4.1


def test_vit_grid_and_input_check():
    vit = ViT(SMALL_VIT).eval()
    assert SMALL_VIT.grid == (16, 12)
    with torch.no_grad():
        assert vit(torch.zeros(2, 3, 256, 192)).shape == (2, 64, 16, 12)
    with pytest.raises(ValueError, match="256, 192"):
        vit(torch.zeros(1, 3, 256, 256))


# ---- official layouts --------------------------------------------------------------------------------------------
VITPOSE_KEYS_DEPTH1 = [
    "backbone.pos_embed", "backbone.patch_embed.proj.weight", "backbone.patch_embed.proj.bias",
    *[f"backbone.blocks.0.{k}" for k in ("norm1.weight", "norm1.bias", "attn.qkv.weight", "attn.qkv.bias",
                                          "attn.proj.weight", "attn.proj.bias", "norm2.weight", "norm2.bias",
                                          "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight", "mlp.fc2.bias")],
    "backbone.last_norm.weight", "backbone.last_norm.bias", "keypoint_head.deconv_layers.0.weight",
    *[f"keypoint_head.deconv_layers.{i}.{k}" for i in (1, 4)
      for k in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")],
    "keypoint_head.deconv_layers.3.weight", "keypoint_head.final_layer.weight", "keypoint_head.final_layer.bias"]


def test_vitpose_key_layout_is_mmpose():
    model = ViTPose(ViTConfig(embed_dim=32, depth=1, num_heads=2))
    assert sorted(model.state_dict()) == sorted(VITPOSE_KEYS_DEPTH1)


def randomized(model):
    torch.manual_seed(0)
    with torch.no_grad():
        for name, p in model.state_dict().items():
            if p.dtype.is_floating_point:
                p.copy_(torch.randn_like(p) * (0.2 if "weight" in name or "embed" in name else 0.05))
                if "running_var" in name:
                    p.abs_().add_(0.5)
    return model.eval()


@pytest.fixture(scope="module")
def vitpose_file(tmp_path_factory):
    model = randomized(ViTPose(SMALL_VIT))
    path = tmp_path_factory.mktemp("vitpose") / "vitpose-small.pth"
    torch.save({"meta": {"mmpose_version": "0.24.0"}, "state_dict": model.state_dict()}, path)
    return path, model


def test_vitpose_loads_official_layout(vitpose_file):
    path, model = vitpose_file
    loaded = load_vitpose(path, num_heads=4)
    x = torch.randn(2, 3, 256, 192)
    with torch.no_grad():
        np.testing.assert_array_equal(loaded(x).numpy(), model(x).numpy())
    assert loaded(x).shape == (2, 17, 64, 48)


def test_vitpose_loader_errors(vitpose_file, tmp_path):
    path, model = vitpose_file
    with pytest.raises(ckpt.CheckpointNotFoundError, match="ViTPose.*ViTAE-Transformer/ViTPose"):
        load_vitpose(tmp_path / "missing.pth")
    with pytest.raises(ckpt.CheckpointError, match="official size.*num_heads"):
        load_vitpose(path)
    state = dict(model.state_dict())
    del state["keypoint_head.final_layer.weight"]
    torch.save({"state_dict": state}, tmp_path / "broken.pth")
    with pytest.raises(ckpt.CheckpointError, match=r"missing keys keypoint_head\.final_layer\.weight \(17, 256, 1, "
                                                   r"1\).*expected layout.*OneDrive"):
        load_vitpose(tmp_path / "broken.pth", num_heads=4)


def test_flip_back_inverts_a_mirrored_image():
    h = torch.randn(2, 17, 8, 6)
    order = list(range(17))
    for a, b in COCO_FLIP_PAIRS:
        order[a], order[b] = b, a
    mirrored = h[:, order].flip(3)  # what a perfect model returns on the mirrored image
    np.testing.assert_array_equal(flip_back(mirrored).numpy(), h.numpy())


def test_flip_test_averages_direct_and_mirrored(vitpose_file):
    _, model = vitpose_file
    x = torch.randn(1, 3, 256, 192)
    with torch.no_grad():
        expected = 0.5 * (model(x) + flip_back(model(x.flip(3))))
        np.testing.assert_allclose(model.heatmaps(x, True).numpy(), expected.numpy(), rtol=1e-6)
        np.testing.assert_array_equal(model.heatmaps(x, False).numpy(), model(x).numpy())


# ---- heatmap decoding ------------------------------------------------------------------------------------------
def gaussian_maps(centres, shape=(64, 48), sigma=2.0):
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    return np.stack([np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * sigma ** 2)) for cx, cy in centres])


def test_dark_recovers_subpixel_peaks():
    rng = np.random.default_rng(0)
    centres = np.column_stack([rng.uniform(6, 42, 17), rng.uniform(6, 58, 17)])
    coords, scores = decode_heatmaps(gaussian_maps(centres)[None])
    np.testing.assert_allclose(coords[0], centres, atol=0.02)  # the argmax alone is off by up to 0.5 px
    assert np.abs(np.round(centres) - centres).max() > 0.3
    assert (scores > 0.8).all() and (scores <= 1).all()


def reference_decode(hm, kernel=11):
    """One map at a time: explicit separable Gaussian (OpenCV's sigma for the size, reflect-101 borders), log,
    Newton step from the central-difference gradient and Hessian at the integer maximum, taken only at a peak
    (negative definite Hessian, step within a pixel)."""
    sigma = 0.3 * ((kernel - 1) * 0.5 - 1) + 0.8
    t = np.arange(kernel) - kernel // 2
    g = np.exp(-t ** 2 / (2 * sigma ** 2))
    g /= g.sum()
    out = []
    for m in hm:
        p = np.pad(m.astype(np.float64), kernel // 2, mode="reflect")
        rows = np.array([[np.dot(p[i, j:j + kernel], g) for j in range(m.shape[1])] for i in range(p.shape[0])])
        blur = np.array([[np.dot(rows[i:i + kernel, j], g) for j in range(m.shape[1])] for i in range(m.shape[0])])
        L = np.log(np.clip(blur, 0.001, 50))
        y, x = np.unravel_index(np.argmax(m), m.shape)

        def f(dx, dy):
            return L[min(max(y + dy, 0), m.shape[0] - 1), min(max(x + dx, 0), m.shape[1] - 1)]

        grad = np.array([(f(1, 0) - f(-1, 0)) / 2, (f(0, 1) - f(0, -1)) / 2])
        dxy = (f(1, 1) - f(1, 0) - f(0, 1) + 2 * f(0, 0) - f(-1, 0) - f(0, -1) + f(-1, -1)) / 2
        hess = np.array([[f(1, 0) - 2 * f(0, 0) + f(-1, 0), dxy], [dxy, f(0, 1) - 2 * f(0, 0) + f(0, -1)]])
        hess = hess + np.finfo(np.float32).eps * np.eye(2)
        step = np.linalg.solve(hess, grad)
        peaked = np.all(np.linalg.eigvalsh(hess) < 0) and np.abs(step).max() <= 1
        out.append(np.array([x, y]) - (step if peaked else 0))
    return np.array(out)


def test_decoding_matches_numpy_reference_on_network_heatmaps(vitpose_file):
    _, model = vitpose_file
    with torch.no_grad():
        hm = model.heatmaps(torch.randn(1, 3, 256, 192)).numpy()
    hm = np.abs(hm) + gaussian_maps([(20.3, 30.7)] * 17) * 3  # peaked maps with network noise on top
    coords, _ = decode_heatmaps(hm)
    expected = reference_decode(hm[0])
    np.testing.assert_allclose(coords[0], expected, atol=1e-4)
    assert (np.abs(expected - np.round(expected)) > 0.01).any()  # some maps were refined, some kept
    assert (np.abs(expected - np.round(expected)) < 1e-9).any()


def test_heatmap_to_frame_udp_alignment():
    g = InputGeometry(origin=np.array([100.0, 50.0]), scale=np.array([2.0, 2.0]))
    corners = heatmap_to_frame(np.array([[0.0, 0.0], [47.0, 63.0]]), g)
    np.testing.assert_allclose(corners, [[100.0, 50.0], [100.0 + 2 * 191, 50.0 + 2 * 255]])


# ---- HMR 2.0 ---------------------------------------------------------------------------------------------------
def test_hmr2_decoder_key_layout_is_4d_humans():
    keys = set(HMR2(ViTConfig(embed_dim=64, depth=1, num_heads=4), SMALL_DECODER).state_dict())
    layer = "smpl_head.transformer.transformer.layers.0."
    expected = {"smpl_head.transformer.to_token_embedding.weight", "smpl_head.transformer.to_token_embedding.bias",
                "smpl_head.transformer.pos_embedding", layer + "0.norm.weight", layer + "0.norm.bias",
                layer + "0.fn.to_qkv.weight", layer + "0.fn.to_out.0.weight", layer + "0.fn.to_out.0.bias",
                layer + "1.norm.weight", layer + "1.norm.bias", layer + "1.fn.to_kv.weight", layer + "1.fn.to_q.weight",
                layer + "1.fn.to_out.0.weight", layer + "1.fn.to_out.0.bias", layer + "2.norm.weight",
                layer + "2.norm.bias", layer + "2.fn.net.0.weight", layer + "2.fn.net.0.bias",
                layer + "2.fn.net.3.weight", layer + "2.fn.net.3.bias", "smpl_head.decpose.weight",
                "smpl_head.decpose.bias", "smpl_head.decshape.weight", "smpl_head.decshape.bias",
                "smpl_head.deccam.weight", "smpl_head.deccam.bias", "smpl_head.init_body_pose",
                "smpl_head.init_betas", "smpl_head.init_cam"}
    assert {k for k in keys if k.startswith("smpl_head.") and ".layers.1." not in k} == expected


@pytest.fixture(scope="module")
def hmr2_file(tmp_path_factory):
    model = randomized(HMR2(SMALL_VIT, SMALL_DECODER))
    with torch.no_grad():
        model.smpl_head.init_cam.copy_(torch.tensor([[0.9, 0.0, 0.0]]))
    root = tmp_path_factory.mktemp("hmr2")
    (root / "checkpoints").mkdir()
    path = root / "checkpoints" / "epoch=35-step=1000000.ckpt"
    state = {**model.state_dict(), "smpl.shapedirs": torch.zeros(6890, 3, 10),
             "discriminator.D_conv1.weight": torch.zeros(32, 9, 1, 1), "initialized": torch.tensor(True)}
    d = SMALL_DECODER
    # 4D-Humans saves its yacs config as the Lightning module's hyper-parameters (save_hyperparameters)
    cfg_node = named_class("yacs.config.CfgNode")
    with importable(cfg_node):
        hparams = {"cfg": cfg_node(MODEL=cfg_node(IMAGE_SIZE=256)), "init_renderer": False}
        torch.save({"epoch": 35, "global_step": 1000000, "pytorch-lightning_version": "2.0.0", "state_dict": state,
                    "hyper_parameters": hparams}, path)
    config = {"MODEL": {"IMAGE_SIZE": 256, "BACKBONE": {"TYPE": "vit"}, "SMPL_HEAD": {
        "TYPE": "transformer_decoder", "IN_CHANNELS": 2048, "TRANSFORMER_DECODER": {
            "depth": d.depth, "heads": d.heads, "mlp_dim": d.mlp_dim, "dim_head": d.dim_head, "dropout": 0.0,
            "emb_dropout": 0.0, "norm": "layer", "context_dim": 64}}}, "EXTRA": {"FOCAL_LENGTH": 5000}}
    (root / "model_config.yaml").write_text(yaml.safe_dump(config))
    return path, model


def test_hmr2_loads_lightning_checkpoint(hmr2_file):
    path, model = hmr2_file
    loaded = load_hmr2(path, backbone_heads=4)
    x = torch.randn(2, 3, 256, 256)
    with torch.no_grad():
        a, b = loaded(x), model(x)
    for name in ("rotmats", "pose", "betas", "crop_cam", "features"):
        np.testing.assert_array_equal(getattr(a, name).numpy(), getattr(b, name).numpy())
    R = a.rotmats.double()
    np.testing.assert_allclose(R @ R.transpose(-1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
    np.testing.assert_allclose(torch.linalg.det(R).numpy(), 1.0, atol=1e-5)
    np.testing.assert_allclose(Rotation.from_rotvec(a.pose.reshape(-1, 3).double().numpy()).as_matrix(),
                               R.reshape(-1, 3, 3).numpy(), atol=1e-4)
    assert a.betas.shape == (2, 10) and a.crop_cam.shape == (2, 3) and a.features.shape == (2, 32)


def test_hmr2_only_reads_the_central_columns(hmr2_file):
    _, model = hmr2_file
    x = torch.randn(1, 3, 256, 256)
    y = x.clone()
    y[..., :32] = 5.0
    y[..., 224:] = -5.0
    with torch.no_grad():
        np.testing.assert_array_equal(model(x).crop_cam.numpy(), model(y).crop_cam.numpy())


def test_hmr2_loader_errors(hmr2_file, tmp_path):
    path, model = hmr2_file
    with pytest.raises(ckpt.CheckpointNotFoundError, match="HMR 2.0.*hmr2_data.tar.gz"):
        load_hmr2(tmp_path / "nope.ckpt")
    with pytest.raises(ckpt.CheckpointNotFoundError, match="model config not found"):
        load_hmr2(path, tmp_path / "model_config.yaml", backbone_heads=4)
    bad = tmp_path / "model_config.yaml"
    bad.write_text(yaml.safe_dump({"MODEL": {"SMPL_HEAD": {"TYPE": "hmr"}}}))
    with pytest.raises(ckpt.CheckpointError, match="transformer_decoder"):
        load_hmr2(path, bad, backbone_heads=4)


def test_hmr2_6d_columns_convention():
    """With the readout zeroed the output is the mean pose: its 6D holds the first two columns of R."""
    model = HMR2(SMALL_VIT, SMALL_DECODER).eval()
    R = Rotation.from_rotvec(np.random.default_rng(3).normal(size=(24, 3))).as_matrix()
    six = np.concatenate([R[:, :, 0], R[:, :, 1]], axis=1).reshape(1, 144)
    with torch.no_grad():
        model.smpl_head.decpose.weight.zero_()
        model.smpl_head.decpose.bias.zero_()
        model.smpl_head.init_body_pose.copy_(torch.from_numpy(six))
        out = model(torch.zeros(1, 3, 256, 256))
    np.testing.assert_allclose(out.rotmats[0].double().numpy(), R, atol=1e-5)


def test_crop_camera_matches_hmr2_projection():
    """HMR 2.0 projects with t = (tx, ty, 2 f / (256 s)) and focal f / 256 on [-0.5, 0.5] crop coordinates; the
    full-image translation of crop_to_full_camera must put the body origin on the same frame pixel."""
    rng = np.random.default_rng(5)
    K = np.array([1100.0, 1100.0, 480.0, 270.0])
    for _ in range(5):
        s, tx, ty = rng.uniform(0.5, 1.5), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
        x0, y0, side = rng.uniform(0, 500), rng.uniform(0, 200), rng.uniform(100, 300)
        tz = 2 * FOCAL_LENGTH / (256 * s)
        crop_norm = FOCAL_LENGTH / 256 * np.array([tx, ty]) / tz  # in [-0.5, 0.5] of the crop
        expected = np.array([x0, y0]) + side * (crop_norm + 0.5)
        t = crop_to_full_camera([s, tx, ty], [x0, y0, x0 + side, y0 + side], K)[0]
        np.testing.assert_allclose(K[:2] * t[:2] / t[2] + K[2:], expected, rtol=1e-10)


# ---- a real frame ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def real_frame():
    import cv2

    cap = cv2.VideoCapture(str(CLIP))
    ok, frame = cap.read()
    cap.release()
    assert ok, f"cannot read {CLIP}"
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)


def test_networks_on_a_real_frame(real_frame, vitpose_file, hmr2_file):
    box = np.array([400.0, 150.0, 560.0, 500.0])
    vitpose, hmr2 = load_vitpose(vitpose_file[0], num_heads=4), load_hmr2(hmr2_file[0], backbone_heads=4)
    a = network_input(real_frame, box, size=(256, 192))
    b = network_input(real_frame, box, size=(256, 256))
    assert a.image.shape == (256, 192, 3) and b.image.shape == (256, 256, 3)
    with torch.no_grad():
        hm = vitpose.heatmaps(normalize_images(torch.from_numpy(a.image[None])))
        out = hmr2(normalize_images(torch.from_numpy(b.image[None])))
    coords, scores = decode_heatmaps(hm.numpy())
    uv = heatmap_to_frame(coords[0], a)
    assert np.isfinite(uv).all() and np.isfinite(scores).all()
    # Every keypoint lies in the network's input region (which holds the whole padded box).
    assert (uv >= a.region[:2] - 1).all() and (uv <= a.region[2:] + 1).all()
    assert torch.isfinite(out.pose).all() and torch.isfinite(out.crop_cam).all()


def test_a_heatmap_peak_decodes_to_its_frame_pixel(real_frame):
    """network_input's placement, the UDP heatmap alignment and DARK together: a peak put where a frame pixel
    falls in the heatmap decodes back to that pixel."""
    net = network_input(real_frame, [400.0, 150.0, 560.0, 500.0], size=(256, 192))
    targets = np.array([[430.3, 200.6], [500.0, 321.2], [455.7, 470.9]])
    ratio = np.array([191 / 47, 255 / 63])
    in_heatmap = (targets - net.origin) / net.scale / ratio
    coords, _ = decode_heatmaps(gaussian_maps(in_heatmap)[None])
    np.testing.assert_allclose(heatmap_to_frame(coords[0], net), targets, atol=0.05 * net.scale[0] * ratio[0])
