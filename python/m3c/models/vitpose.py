"""ViTPose (Xu et al. 2022): 17 COCO keypoints from a person-centred 256 x 192 image, in the layout of the official
mmpose checkpoints (ViTAE-Transformer/ViTPose, configs ViTPose_{base,large,huge}_coco_256x192.py).

    backbone        m3c.models.vit.ViT: (B, 3, 256, 192) -> (B, C, 16, 12)
    keypoint_head   the "classic" decoder: deconv_layers = [ConvTranspose2d(C, 256, 4, stride 2, padding 1, no
                    bias), BatchNorm2d, ReLU] x 2, final_layer Conv2d(256, 17, 1) -> heatmaps (B, 17, 64, 48)

Test-time settings of those configs, reproduced here: flip test (the mirrored image's heatmaps, left/right channels
swapped and flipped back, averaged with the direct ones, no heatmap shift), unbiased data processing (UDP: input
pixel i and heatmap pixel j meet at i = j (w_in - 1) / (w_hm - 1)) and the DARK refinement of each heatmap maximum
(Gaussian blur with an 11 px kernel, log, one Newton step from the finite-difference gradient and Hessian).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from m3c.models import checkpoint as ckpt
from m3c.models.vit import ViT, ViTConfig

NUM_KEYPOINTS = 17
HEATMAP_SIZE = (64, 48)  # (height, width)
DECONV_FILTERS = 256
DARK_KERNEL = 11  # test_cfg modulate_kernel: the blur that matches the training heatmaps' sigma 2
# COCO-17 left/right pairs (eyes, ears, shoulders, elbows, wrists, hips, knees, ankles).
COCO_FLIP_PAIRS = ((1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16))
# Heads of each official size (not recoverable from the weights' shapes).
HEADS_BY_WIDTH = {384: 12, 768: 12, 1024: 16, 1280: 16}

VITPOSE_SOURCE = ckpt.CheckpointSource(
    model="ViTPose",
    default_path="vitpose/vitpose-h.pth",
    obtain=("download ViTPose-H (or -B/-L), 256x192, COCO, from the OneDrive links in the README of "
            "github.com/ViTAE-Transformer/ViTPose (an mmpose checkpoint: a dict with 'state_dict' holding "
            "backbone.* and keypoint_head.* tensors; split a multi-dataset model first with the repository's "
            "tools/model_split.py and use its coco.pth)."),
)


class HeatmapHead(nn.Module):
    """mmpose's TopdownHeatmapSimpleHead with two 4x4 deconvolutions and a 1x1 output convolution."""

    def __init__(self, in_channels: int, num_keypoints: int = NUM_KEYPOINTS, filters: int = DECONV_FILTERS):
        super().__init__()
        self.deconv_layers = nn.Sequential(
            nn.ConvTranspose2d(in_channels, filters, 4, stride=2, padding=1, output_padding=0, bias=False),
            nn.BatchNorm2d(filters), nn.ReLU(inplace=True),
            nn.ConvTranspose2d(filters, filters, 4, stride=2, padding=1, output_padding=0, bias=False),
            nn.BatchNorm2d(filters), nn.ReLU(inplace=True))
        self.final_layer = nn.Conv2d(filters, num_keypoints, kernel_size=1)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.final_layer(self.deconv_layers(features))


class ViTPose(nn.Module):
    def __init__(self, config: ViTConfig = ViTConfig()):
        super().__init__()
        self.backbone = ViT(config)
        self.keypoint_head = HeatmapHead(config.embed_dim)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """images (B, 3, 256, 192) normalised (m3c.models.vit.normalize_images) -> heatmaps (B, 17, 64, 48)."""
        return self.keypoint_head(self.backbone(images))

    @torch.no_grad()
    def heatmaps(self, images: torch.Tensor, flip_test: bool = True) -> torch.Tensor:
        """The test-time heatmaps: with flip_test, the average of the image's and its mirror's (flipped back)."""
        out = self(images)
        if flip_test:
            out = 0.5 * (out + flip_back(self(images.flip(3))))
        return out


def flip_back(heatmaps: torch.Tensor, pairs=COCO_FLIP_PAIRS) -> torch.Tensor:
    """Heatmaps of a horizontally mirrored image -> heatmaps of the original: left/right channels swapped, then
    mirrored (no shift: with UDP the mirror of heatmap column j is column W - 1 - j)."""
    order = list(range(heatmaps.shape[1]))
    for left, right in pairs:
        order[left], order[right] = right, left
    return heatmaps[:, order].flip(3)


def decode_heatmaps(heatmaps: np.ndarray, kernel: int = DARK_KERNEL) -> tuple[np.ndarray, np.ndarray]:
    """Heatmaps (N, K, H, W) -> (coordinates (N, K, 2) x, y in heatmap pixels, scores (N, K) = each map's maximum).

    Each map's maximum is refined by DARK as mmpose's post_dark_udp does: the map is blurred with a Gaussian of
    `kernel` pixels (OpenCV's sigma for that size), clipped to [0.001, 50] and logged; the peak moves by one Newton
    step -H^-1 g, with g and H central differences of the log map at the integer maximum (borders replicated).
    Where the log map is not peaked there (H not negative definite, or a step over a pixel) the integer maximum
    is kept.
    """
    import cv2

    hm = np.asarray(heatmaps, dtype=np.float32)
    if hm.ndim != 4:
        raise ValueError(f"heatmaps must be (N, K, H, W), got shape {hm.shape}")
    N, K, H, W = hm.shape
    flat = hm.reshape(N, K, -1)
    idx = flat.argmax(axis=2)
    scores = flat.max(axis=2)
    x, y = (idx % W).astype(np.int64), (idx // W).astype(np.int64)
    blurred = np.empty_like(hm)
    for n in range(N):
        for k in range(K):
            blurred[n, k] = cv2.GaussianBlur(hm[n, k], (kernel, kernel), 0)
    log = np.log(np.clip(blurred, 0.001, 50.0))
    pad = np.pad(log, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    n_idx, k_idx = np.meshgrid(np.arange(N), np.arange(K), indexing="ij")
    px, py = x + 1, y + 1

    def at(dx: int, dy: int) -> np.ndarray:
        return pad[n_idx, k_idx, py + dy, px + dx].astype(np.float64)

    c = at(0, 0)
    gx, gy = 0.5 * (at(1, 0) - at(-1, 0)), 0.5 * (at(0, 1) - at(0, -1))
    hxx = at(1, 0) - 2 * c + at(-1, 0)
    hyy = at(0, 1) - 2 * c + at(0, -1)
    hxy = 0.5 * (at(1, 1) - at(1, 0) - at(0, 1) + 2 * c - at(-1, 0) - at(0, -1) + at(-1, -1))
    eps = np.finfo(np.float32).eps
    hxx, hyy = hxx + eps, hyy + eps
    det = hxx * hyy - hxy * hxy
    # A peak has a negative definite Hessian and moves by less than a pixel; elsewhere (flat or noisy maps, where
    # mmpose's step can leave the map) the integer maximum stays.
    peak = (det > 1e-12) & (hxx < 0)
    det = np.where(peak, det, 1.0)
    step_x = (hyy * gx - hxy * gy) / det
    step_y = (hxx * gy - hxy * gx) / det
    peak &= (np.abs(step_x) <= 1.0) & (np.abs(step_y) <= 1.0)
    coords = np.stack([x - np.where(peak, step_x, 0.0), y - np.where(peak, step_y, 0.0)], axis=-1)
    return coords, scores.astype(np.float64)


@dataclass(frozen=True)
class InputGeometry:
    """How network-input pixels map to frame pixels: frame = origin + scale * input (x and y)."""

    origin: np.ndarray  # (2,) frame position of input pixel (0, 0)
    scale: np.ndarray  # (2,) frame pixels per input pixel


def heatmap_to_frame(coords: np.ndarray, geometry: InputGeometry, input_size=(256, 192),
                     heatmap_size=HEATMAP_SIZE) -> np.ndarray:
    """Heatmap coordinates (..., 2) -> frame pixels, with UDP's alignment (heatmap pixel j sits at input pixel
    j (w_in - 1) / (w_hm - 1))."""
    ratio = np.array([(input_size[1] - 1) / (heatmap_size[1] - 1), (input_size[0] - 1) / (heatmap_size[0] - 1)])
    return geometry.origin + geometry.scale * (np.asarray(coords) * ratio)


def infer_config(state: dict, num_heads: int | None, path, source: ckpt.CheckpointSource,
                 prefix: str = "backbone.") -> ViTConfig:
    """The ViT size of a state dict from its shapes (heads from the official sizes unless given)."""
    key = prefix + "patch_embed.proj.weight"
    if key not in state:
        raise ckpt.CheckpointError(f"{path}: no {key} (found {list(state)[:6]}). {source.hint()}")
    width = int(state[key].shape[0])
    depth = 0
    while f"{prefix}blocks.{depth}.norm1.weight" in state:
        depth += 1
    if num_heads is None:
        if width not in HEADS_BY_WIDTH:
            raise ckpt.CheckpointError(f"{path}: a ViT of width {width} is not an official size "
                                       f"({sorted(HEADS_BY_WIDTH)}); give num_heads. {source.hint()}")
        num_heads = HEADS_BY_WIDTH[width]
    hidden = int(state[prefix + "blocks.0.mlp.fc1.weight"].shape[0]) if depth else 4 * width
    return ViTConfig(width, depth, num_heads, hidden / width)


def load_vitpose(path: str | os.PathLike | None = None, num_heads: int | None = None) -> ViTPose:
    """ViTPose from an official mmpose checkpoint ('state_dict' -> backbone.*, keypoint_head.*); the ViT's size is
    read from the weights. path None -> $M3C_MODELS/vitpose/vitpose-h.pth. Eval mode."""
    file = ckpt.resolve_path(path, VITPOSE_SOURCE)
    raw = ckpt.read_checkpoint(file, VITPOSE_SOURCE)
    state = ckpt.strip_prefix(ckpt.take_state_dict(raw, ("state_dict", "model", ""), file, VITPOSE_SOURCE),
                              "module.")
    model = ViTPose(infer_config(state, num_heads, file, VITPOSE_SOURCE))
    ckpt.load_into(model, state, file, VITPOSE_SOURCE, optional_suffixes=("num_batches_tracked",))
    return model.eval()


__all__ = ["COCO_FLIP_PAIRS", "HEATMAP_SIZE", "HeatmapHead", "InputGeometry", "VITPOSE_SOURCE", "ViTPose",
           "decode_heatmaps", "flip_back", "heatmap_to_frame", "infer_config", "load_vitpose"]
