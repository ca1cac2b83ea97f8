"""The plain Vision Transformer that ViTPose (Xu et al. 2022) and HMR 2.0 (Goel et al. 2023) share, in the layout of
their official checkpoints (ViTPose's mmpose backbone, which 4D-Humans reuses unchanged).

    patch_embed.proj   Conv2d(3, C, kernel 16, stride 16, padding 2): a 256 x 192 image -> 16 x 12 tokens
    pos_embed          (1, 1 + 16 * 12, C): slot 0 is a class-token position that is added to every token
    blocks.i           pre-norm transformer blocks: norm1 -> attn (qkv with bias, proj) ; norm2 -> mlp (fc1, GELU, fc2)
    last_norm          LayerNorm over the output tokens
LayerNorms use eps 1e-6. The output is the token grid as a feature map (B, C, 16, 12). Sizes (embed dim, depth,
heads): ViT-B 768/12/12, ViT-L 1024/24/16, ViT-H 1280/32/16; ViTPose-H and HMR 2.0 use ViT-H.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

IMAGE_SIZE = (256, 192)  # (height, width) the backbone reads
PATCH_SIZE = 16
PATCH_PADDING = 2  # ViTPose's PatchEmbed: padding 4 + 2 * (ratio // 2 - 1) with ratio 1
LAYER_NORM_EPS = 1e-6
# ImageNet statistics, RGB in [0, 1]: the input normalisation of both ViTPose and HMR 2.0.
IMAGE_MEAN = (0.485, 0.456, 0.406)
IMAGE_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class ViTConfig:
    embed_dim: int = 1280
    depth: int = 32
    num_heads: int = 16
    mlp_ratio: float = 4.0
    image_size: tuple = IMAGE_SIZE

    @classmethod
    def size(cls, name: str) -> "ViTConfig":
        """'base', 'large' or 'huge' (ViTPose's B/L/H)."""
        sizes = {"base": (768, 12, 12), "large": (1024, 24, 16), "huge": (1280, 32, 16)}
        if name not in sizes:
            raise ValueError(f"unknown ViT size {name!r}; sizes are {', '.join(sizes)}")
        dim, depth, heads = sizes[name]
        return cls(dim, depth, heads)

    def __post_init__(self):
        if self.embed_dim % self.num_heads:
            raise ValueError(f"embed_dim {self.embed_dim} must be divisible by num_heads {self.num_heads}")

    @property
    def grid(self) -> tuple[int, int]:
        """Token rows and columns for image_size (the convolution's output size)."""
        h, w = self.image_size
        return ((h + 2 * PATCH_PADDING - PATCH_SIZE) // PATCH_SIZE + 1,
                (w + 2 * PATCH_PADDING - PATCH_SIZE) // PATCH_SIZE + 1)


class PatchEmbed(nn.Module):
    def __init__(self, embed_dim: int):
        super().__init__()
        self.proj = nn.Conv2d(3, embed_dim, kernel_size=PATCH_SIZE, stride=PATCH_SIZE, padding=PATCH_PADDING)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x)


class Attention(nn.Module):
    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, 3 * dim, bias=True)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)  # softmax(q k^T / sqrt(head_dim)) v
        return self.proj(out.transpose(1, 2).reshape(B, N, C))


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class Block(nn.Module):
    def __init__(self, dim: int, num_heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=LAYER_NORM_EPS)
        self.attn = Attention(dim, num_heads)
        self.norm2 = nn.LayerNorm(dim, eps=LAYER_NORM_EPS)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class ViT(nn.Module):
    """images (B, 3, H, W) normalised with IMAGE_MEAN / IMAGE_STD, (H, W) = config.image_size -> features
    (B, C, H/16, W/16)."""

    def __init__(self, config: ViTConfig = ViTConfig()):
        super().__init__()
        self.config = config
        rows, cols = config.grid
        self.patch_embed = PatchEmbed(config.embed_dim)
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + rows * cols, config.embed_dim))
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        self.blocks = nn.ModuleList(Block(config.embed_dim, config.num_heads, config.mlp_ratio)
                                    for _ in range(config.depth))
        self.last_norm = nn.LayerNorm(config.embed_dim, eps=LAYER_NORM_EPS)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if images.ndim != 4 or images.shape[1] != 3 or tuple(images.shape[2:]) != tuple(self.config.image_size):
            raise ValueError(f"images must be (B, 3, {self.config.image_size[0]}, {self.config.image_size[1]}), "
                             f"got {tuple(images.shape)}")
        feat = self.patch_embed(images)
        B, C, rows, cols = feat.shape
        # Slot 0 of the table is a class-token position; the official model adds it to every patch token.
        x = feat.flatten(2).transpose(1, 2) + self.pos_embed[:, 1:] + self.pos_embed[:, :1]
        for block in self.blocks:
            x = block(x)
        x = self.last_norm(x)
        return x.transpose(1, 2).reshape(B, C, rows, cols)


def normalize_images(images: torch.Tensor) -> torch.Tensor:
    """uint8 or [0, 255] float images (B, H, W, 3) RGB -> (B, 3, H, W) float normalised with ImageNet's
    statistics."""
    x = images.to(torch.float32).permute(0, 3, 1, 2) / 255.0
    mean = torch.tensor(IMAGE_MEAN, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGE_STD, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    return (x - mean) / std


def parameter_count(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


__all__ = ["IMAGE_MEAN", "IMAGE_SIZE", "IMAGE_STD", "ViT", "ViTConfig", "normalize_images", "parameter_count"]
