"""HMR 2.0 (Goel et al. 2023): a camera-local SMPL body from a person-centred 256 x 256 image, in the layout of the
official 4D-Humans Lightning checkpoint (shubham-goel/4D-Humans, experiment hmr_vit_transformer).

    backbone     m3c.models.vit.ViT-H on the image's central 256 x 192 columns (x[..., 32:-32])
                 -> (B, 1280, 16, 12), read as 192 context tokens
    smpl_head    a transformer decoder: one query token (the scalar 0, to_token_embedding Linear(1, 1024), plus
                 pos_embedding) through 6 layers of [self-attention, cross-attention to the context tokens,
                 feed-forward 1024 -> 1024], each pre-LayerNorm and residual (8 heads of 64, no qkv bias); then
                 decpose (24 x 6D), decshape (10), deccam (3) added to the mean parameters init_body_pose,
                 init_betas, init_cam (IEF_ITERS iterations, 1 in the published model)

Outputs: SMPL global orientation and body pose as rotation matrices (6D: the first two COLUMNS of R are x[:3], x[3:]
Gram-Schmidt orthonormalised), betas (10), and the weak-perspective crop camera (s, tx, ty): a body point X projects
to s (X_xy + t_xy) in [-1, 1] crop coordinates (HMR 2.0's translation is (tx, ty, 2 f / (256 s)) with f = 5000 px at
256 px; m3c.perception.boxes.crop_to_full_camera places it in the full image).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from m3c.models import checkpoint as ckpt
from m3c.models.rotations import matrix_to_axis_angle, rotation_6d_to_matrix_rows
from m3c.models.vit import ViT, ViTConfig
from m3c.models.vitpose import infer_config

IMAGE_SIZE = 256
BACKBONE_COLUMNS = (32, 224)  # the columns of the 256 x 256 crop the ViT reads (256 x 192)
NUM_JOINTS = 24  # SMPL: global orientation + 23 body joints
FOCAL_LENGTH = 5000.0  # cfg.EXTRA.FOCAL_LENGTH, pixels at IMAGE_SIZE

HMR2_SOURCE = ckpt.CheckpointSource(
    model="HMR 2.0",
    default_path="hmr2/checkpoints/epoch=35-step=1000000.ckpt",
    obtain=("download hmr2_data.tar.gz as 4D-Humans does (github.com/shubham-goel/4D-Humans, "
            "hmr2/models/__init__.py: download_models) and use logs/train/multiruns/hmr2/0/checkpoints/"
            "epoch=35-step=1000000.ckpt with its model_config.yaml two folders up (a Lightning checkpoint: "
            "'state_dict' -> backbone.*, smpl_head.*)."),
)


@dataclass(frozen=True)
class DecoderConfig:
    """MODEL.SMPL_HEAD.TRANSFORMER_DECODER of the published config, plus the readout sizes."""

    dim: int = 1024
    depth: int = 6
    heads: int = 8
    dim_head: int = 64
    mlp_dim: int = 1024
    context_dim: int = 1280
    iterations: int = 1  # MODEL.SMPL_HEAD.IEF_ITERS


class PreNorm(nn.Module):
    def __init__(self, dim: int, fn: nn.Module):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.fn = fn

    def forward(self, x, **kwargs):
        return self.fn(self.norm(x), **kwargs)


def _heads(x: torch.Tensor, heads: int) -> torch.Tensor:
    B, N, D = x.shape
    return x.reshape(B, N, heads, D // heads).transpose(1, 2)


class SelfAttention(nn.Module):
    def __init__(self, dim: int, heads: int, dim_head: int):
        super().__init__()
        self.heads = heads
        self.to_qkv = nn.Linear(dim, 3 * heads * dim_head, bias=False)
        self.to_out = nn.Sequential(nn.Linear(heads * dim_head, dim))

    def forward(self, x):
        q, k, v = (_heads(t, self.heads) for t in self.to_qkv(x).chunk(3, dim=-1))
        out = F.scaled_dot_product_attention(q, k, v)
        return self.to_out(out.transpose(1, 2).flatten(2))


class CrossAttention(nn.Module):
    def __init__(self, dim: int, context_dim: int, heads: int, dim_head: int):
        super().__init__()
        self.heads = heads
        self.to_kv = nn.Linear(context_dim, 2 * heads * dim_head, bias=False)
        self.to_q = nn.Linear(dim, heads * dim_head, bias=False)
        self.to_out = nn.Sequential(nn.Linear(heads * dim_head, dim))

    def forward(self, x, context):
        k, v = (_heads(t, self.heads) for t in self.to_kv(context).chunk(2, dim=-1))
        out = F.scaled_dot_product_attention(_heads(self.to_q(x), self.heads), k, v)
        return self.to_out(out.transpose(1, 2).flatten(2))


class FeedForward(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Dropout(0.0), nn.Linear(hidden, dim),
                                 nn.Dropout(0.0))

    def forward(self, x):
        return self.net(x)


class CrossAttentionLayers(nn.Module):
    def __init__(self, c: DecoderConfig):
        super().__init__()
        self.layers = nn.ModuleList(nn.ModuleList([
            PreNorm(c.dim, SelfAttention(c.dim, c.heads, c.dim_head)),
            PreNorm(c.dim, CrossAttention(c.dim, c.context_dim, c.heads, c.dim_head)),
            PreNorm(c.dim, FeedForward(c.dim, c.mlp_dim))]) for _ in range(c.depth))

    def forward(self, x, context):
        for self_attn, cross_attn, ff in self.layers:
            x = self_attn(x) + x
            x = cross_attn(x, context=context) + x
            x = ff(x) + x
        return x


class TransformerDecoder(nn.Module):
    def __init__(self, c: DecoderConfig):
        super().__init__()
        self.to_token_embedding = nn.Linear(1, c.dim)
        self.pos_embedding = nn.Parameter(torch.randn(1, 1, c.dim))
        self.transformer = CrossAttentionLayers(c)

    def forward(self, token, context):
        return self.transformer(self.to_token_embedding(token) + self.pos_embedding, context)


class SMPLHead(nn.Module):
    def __init__(self, c: DecoderConfig):
        super().__init__()
        self.config = c
        self.transformer = TransformerDecoder(c)
        self.decpose = nn.Linear(c.dim, 6 * NUM_JOINTS)
        self.decshape = nn.Linear(c.dim, 10)
        self.deccam = nn.Linear(c.dim, 3)
        # The mean parameters (smpl_mean_params.npz), stored in the checkpoint; identity rotations until loaded.
        self.register_buffer("init_body_pose", torch.tensor([[1.0, 0, 0, 0, 1, 0] * NUM_JOINTS]))
        self.register_buffer("init_betas", torch.zeros(1, 10))
        self.register_buffer("init_cam", torch.tensor([[0.9, 0.0, 0.0]]))

    def forward(self, features: torch.Tensor):
        """features (B, C, h, w) -> (6D pose (B, 144), betas (B, 10), crop camera (B, 3), token (B, dim))."""
        B = features.shape[0]
        context = features.flatten(2).transpose(1, 2)
        pose, betas, cam = (p.expand(B, -1) for p in (self.init_body_pose, self.init_betas, self.init_cam))
        token_out = None
        for _ in range(self.config.iterations):
            token = torch.zeros(B, 1, 1, dtype=features.dtype, device=features.device)
            token_out = self.transformer(token, context).squeeze(1)
            pose = self.decpose(token_out) + pose
            betas = self.decshape(token_out) + betas
            cam = self.deccam(token_out) + cam
        return pose, betas, cam, token_out


@dataclass
class HMR2Output:
    """rotmats (B, 24, 3, 3) SMPL global orientation then body pose; pose (B, 24, 3) the same as axis-angle;
    betas (B, 10); crop_cam (B, 3) weak-perspective (s, tx, ty); features (B, 1024) the decoder's output token
    (WHAM's image feature)."""

    rotmats: torch.Tensor
    pose: torch.Tensor
    betas: torch.Tensor
    crop_cam: torch.Tensor
    features: torch.Tensor


class HMR2(nn.Module):
    def __init__(self, backbone: ViTConfig = ViTConfig(), decoder: DecoderConfig = DecoderConfig()):
        super().__init__()
        if decoder.context_dim != backbone.embed_dim:
            raise ValueError(f"the decoder's context_dim {decoder.context_dim} must equal the ViT's width "
                             f"{backbone.embed_dim}")
        self.backbone = ViT(backbone)
        self.smpl_head = SMPLHead(decoder)

    def forward(self, images: torch.Tensor) -> HMR2Output:
        """images (B, 3, 256, 256) normalised (m3c.models.vit.normalize_images)."""
        if images.ndim != 4 or tuple(images.shape[1:]) != (3, IMAGE_SIZE, IMAGE_SIZE):
            raise ValueError(f"images must be (B, 3, {IMAGE_SIZE}, {IMAGE_SIZE}), got {tuple(images.shape)}")
        features = self.backbone(images[..., BACKBONE_COLUMNS[0]:BACKBONE_COLUMNS[1]])
        pose6d, betas, cam, token = self.smpl_head(features)
        # HMR 2.0's 6D takes x[:3], x[3:] as the first two columns: the transpose of the row convention.
        rotmats = rotation_6d_to_matrix_rows(pose6d.reshape(-1, NUM_JOINTS, 6)).transpose(-1, -2)
        return HMR2Output(rotmats, matrix_to_axis_angle(rotmats), betas, cam, token)


def _read_model_config(path: Path) -> dict:
    import yaml

    try:
        return yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise ckpt.CheckpointError(f"{path}: unreadable HMR 2.0 model config ({err}). {HMR2_SOURCE.hint()}") from err


def model_config_path(checkpoint: Path) -> Path:
    """Where 4D-Humans keeps a checkpoint's config: model_config.yaml two folders up."""
    return checkpoint.parent.parent / "model_config.yaml"


def load_hmr2(path: str | os.PathLike | None = None, config: str | os.PathLike | None = None,
              backbone_heads: int | None = None) -> HMR2:
    """HMR 2.0 from the official Lightning checkpoint ('state_dict' -> backbone.*, smpl_head.*; the SMPL layer's
    and the discriminator's tensors are ignored as at inference). The decoder's settings come from
    model_config.yaml (default: two folders above the checkpoint, as 4D-Humans reads it; without one, the
    published hmr_vit_transformer settings), the sizes from the weights. path None ->
    $M3C_MODELS/hmr2/checkpoints/epoch=35-step=1000000.ckpt. Eval mode."""
    file = ckpt.resolve_path(path, HMR2_SOURCE)
    raw = ckpt.read_checkpoint(file, HMR2_SOURCE)
    state = ckpt.take_state_dict(raw, ("state_dict", ""), file, HMR2_SOURCE)
    cfg_file = Path(config) if config is not None else model_config_path(file)
    if config is not None and not cfg_file.is_file():
        raise ckpt.CheckpointNotFoundError(f"HMR 2.0 model config not found: {cfg_file}. {HMR2_SOURCE.hint()}")
    settings = DecoderConfig()
    if cfg_file.is_file():
        cfg = _read_model_config(cfg_file)
        head = (cfg.get("MODEL") or {}).get("SMPL_HEAD") or {}
        if head.get("TYPE", "transformer_decoder") != "transformer_decoder":
            raise ckpt.CheckpointError(f"{cfg_file}: SMPL_HEAD.TYPE {head.get('TYPE')!r} is not HMR 2.0's "
                                       f"transformer_decoder. {HMR2_SOURCE.hint()}")
        if head.get("TRANSFORMER_INPUT", "zero") != "zero" or head.get("JOINT_REP", "6d") != "6d":
            raise ckpt.CheckpointError(f"{cfg_file}: only the published head (zero input token, 6D joints) is "
                                       f"supported. {HMR2_SOURCE.hint()}")
        dec = head.get("TRANSFORMER_DECODER") or {}
        settings = DecoderConfig(depth=int(dec.get("depth", settings.depth)),
                                 heads=int(dec.get("heads", settings.heads)),
                                 dim_head=int(dec.get("dim_head", settings.dim_head)),
                                 mlp_dim=int(dec.get("mlp_dim", settings.mlp_dim)),
                                 context_dim=int(dec.get("context_dim", settings.context_dim)),
                                 iterations=int(head.get("IEF_ITERS", 1)))
    vit = infer_config(state, backbone_heads, file, HMR2_SOURCE)
    dim_key = "smpl_head.transformer.to_token_embedding.weight"
    dim = int(state[dim_key].shape[0]) if dim_key in state else settings.dim
    settings = DecoderConfig(dim, settings.depth, settings.heads, settings.dim_head, settings.mlp_dim, vit.embed_dim,
                             settings.iterations)
    model = HMR2(vit, settings)
    ckpt.load_into(model, state, file, HMR2_SOURCE, ignore_prefixes=("smpl.", "discriminator.", "initialized", "keypoint_3d_loss.",
                                                                  "keypoint_2d_loss.", "smpl_parameter_loss."))
    return model.eval()


__all__ = ["BACKBONE_COLUMNS", "DecoderConfig", "FOCAL_LENGTH", "HMR2", "HMR2Output", "HMR2_SOURCE", "IMAGE_SIZE",
           "load_hmr2", "model_config_path"]
