"""DPVO's networks (Teed et al. 2023, princeton-vl/DPVO net.py / extractor.py / blocks.py) in torch, in the layout of
the official dpvo.pth, with the correlation lookup (the CUDA altcorr kernel) written in torch.

    patchify.fnet   matching features: conv 7x7 /2 -> 2 residual stages (32, 64 channels, the second /2) -> 1x1 to
                    128 channels, instance norm; /4 resolution, divided by 4 as DPVO does
    patchify.inet   context features: the same encoder without normalisation, 384 channels, divided by 4
    update          the recurrent update operator on edges (patch k of frame i seen in frame j), 384-d state:
                    net += inp + corr_mlp(corr); LayerNorm; += c1(state of the same patch's previous edge);
                    += c2(state of its next edge); += soft aggregation over edges of the same patch (agg_kk) and
                    of the same frame pair (agg_ij); two gated residual units; heads d (2-d flow revision) and
                    w (2-d confidence, sigmoid)

The correlation of an edge: the patch's 3x3 matching features against the target's features at both pyramid
levels (1 and 1/4 of the feature map), on a 7x7 window around each patch pixel's reprojection, bilinearly
interpolated: 2 levels x 49 offsets x 9 pixels = 882 values, in DPVO's order (x offset, y offset, patch row,
patch column, level). Images enter as 2 * (BGR / 255) - 0.5 (DPVO reads frames with OpenCV, so BGR).
"""

from __future__ import annotations

import os

import torch
import torch.nn.functional as F
from torch import nn

from m3c.models import checkpoint as ckpt

DIM = 384  # the update operator's state and the context features
FEATURE_DIM = 128  # matching features
ENCODER_DIM = 32
PATCH_SIZE = 3
RADIUS = 3  # correlation window 7 x 7
LEVELS = (1, 4)
CORR_DIM = len(LEVELS) * (2 * RADIUS + 1) ** 2 * PATCH_SIZE ** 2  # 882
RESOLUTION = 4  # features live at 1/4 of the image
CHUNK = 256  # edges whose correlation windows are gathered at once (memory ~ CHUNK * 9 * 64 * 128 floats)

DPVO_SOURCE = ckpt.CheckpointSource(
    model="DPVO",
    default_path="dpvo/dpvo.pth",
    obtain=("download models.zip from the README of github.com/princeton-vl/DPVO (its download_models_and_data.sh) "
            "and use dpvo.pth (a state dict with 'module.'-prefixed patchify.* and update.* keys)."),
)


class ResidualBlock(nn.Module):
    def __init__(self, in_planes: int, planes: int, norm: str, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(in_planes, planes, 3, padding=1, stride=stride)
        self.conv2 = nn.Conv2d(planes, planes, 3, padding=1)
        self.norm1, self.norm2 = _norm(norm, planes), _norm(norm, planes)
        self.downsample = None
        if stride != 1:
            self.downsample = nn.Sequential(nn.Conv2d(in_planes, planes, 1, stride=stride), _norm(norm, planes))

    def forward(self, x):
        y = F.relu(self.norm1(self.conv1(x)))
        y = F.relu(self.norm2(self.conv2(y)))
        if self.downsample is not None:
            x = self.downsample(x)
        return F.relu(x + y)


def _norm(kind: str, channels: int) -> nn.Module:
    if kind == "instance":
        return nn.InstanceNorm2d(channels)  # no affine parameters, no running statistics (as DPVO's)
    if kind == "none":
        return nn.Sequential()
    raise ValueError(f"unknown norm {kind!r}")


class Encoder(nn.Module):
    """DPVO's BasicEncoder4: (N, 3, H, W) -> (N, output_dim, H/4, W/4)."""

    def __init__(self, output_dim: int, norm: str):
        super().__init__()
        self.conv1 = nn.Conv2d(3, ENCODER_DIM, 7, stride=2, padding=3)
        self.norm1 = _norm(norm, ENCODER_DIM)
        self.layer1 = nn.Sequential(ResidualBlock(ENCODER_DIM, ENCODER_DIM, norm),
                                    ResidualBlock(ENCODER_DIM, ENCODER_DIM, norm))
        self.layer2 = nn.Sequential(ResidualBlock(ENCODER_DIM, 2 * ENCODER_DIM, norm, stride=2),
                                    ResidualBlock(2 * ENCODER_DIM, 2 * ENCODER_DIM, norm))
        self.conv2 = nn.Conv2d(2 * ENCODER_DIM, output_dim, 1)

    def forward(self, x):
        x = F.relu(self.norm1(self.conv1(x)))
        return self.conv2(self.layer2(self.layer1(x)))


class Patchifier(nn.Module):
    def __init__(self):
        super().__init__()
        self.fnet = Encoder(FEATURE_DIM, "instance")
        self.inet = Encoder(DIM, "none")


class GatedResidual(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.gate = nn.Sequential(nn.Linear(dim, dim), nn.Sigmoid())
        self.res = nn.Sequential(nn.Linear(dim, dim), nn.ReLU(inplace=True), nn.Linear(dim, dim))

    def forward(self, x):
        return x + self.gate(x) * self.res(x)


class SoftAgg(nn.Module):
    """Softmax-weighted sum of f(x) over the edges of each group, through h, handed back to every edge."""

    def __init__(self, dim: int):
        super().__init__()
        self.f, self.g, self.h = nn.Linear(dim, dim), nn.Linear(dim, dim), nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, group: torch.Tensor) -> torch.Tensor:
        """x (1, E, D), group (E,) any integer labels."""
        _, index = torch.unique(group, return_inverse=True)
        G, D = int(index.max()) + 1 if index.numel() else 0, x.shape[-1]
        g, f = self.g(x[0]), self.f(x[0])
        idx = index[:, None].expand(-1, D)
        top = torch.full((G, D), -torch.inf, dtype=x.dtype, device=x.device).scatter_reduce(
            0, idx, g, "amax", include_self=True)
        e = torch.exp(g - top[index])
        total = torch.zeros(G, D, dtype=x.dtype, device=x.device).index_add_(0, index, e)
        y = torch.zeros(G, D, dtype=x.dtype, device=x.device).index_add_(0, index, f * e / total[index])
        return self.h(y)[index][None]


def temporal_neighbors(kk: torch.Tensor, jj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For each edge, the edge of the same patch with the next smaller / larger target frame (-1 if none); ties
    keep the edges' order (DPVO's fastba.neighbors)."""
    E = kk.numel()
    order = sorted(range(E), key=lambda e: (int(kk[e]), int(jj[e]), e))
    prev = torch.full((E,), -1, dtype=torch.long)
    nxt = torch.full((E,), -1, dtype=torch.long)
    for a, b in zip(order[:-1], order[1:]):
        if int(kk[a]) == int(kk[b]):
            prev[b], nxt[a] = a, b
    return prev.to(kk.device), nxt.to(kk.device)


class Update(nn.Module):
    def __init__(self):
        super().__init__()
        self.c1 = nn.Sequential(nn.Linear(DIM, DIM), nn.ReLU(inplace=True), nn.Linear(DIM, DIM))
        self.c2 = nn.Sequential(nn.Linear(DIM, DIM), nn.ReLU(inplace=True), nn.Linear(DIM, DIM))
        self.norm = nn.LayerNorm(DIM, eps=1e-3)
        self.agg_kk = SoftAgg(DIM)
        self.agg_ij = SoftAgg(DIM)
        self.gru = nn.Sequential(nn.LayerNorm(DIM, eps=1e-3), GatedResidual(DIM), nn.LayerNorm(DIM, eps=1e-3),
                                 GatedResidual(DIM))
        self.corr = nn.Sequential(nn.Linear(CORR_DIM, DIM), nn.ReLU(inplace=True), nn.Linear(DIM, DIM),
                                  nn.LayerNorm(DIM, eps=1e-3), nn.ReLU(inplace=True), nn.Linear(DIM, DIM))
        self.d = nn.Sequential(nn.ReLU(inplace=False), nn.Linear(DIM, 2))
        self.w = nn.Sequential(nn.ReLU(inplace=False), nn.Linear(DIM, 2), nn.Sigmoid())

    def forward(self, net, inp, corr, ii, jj, kk):
        """net, inp (1, E, 384) edge states and their patches' context; corr (1, E, 882); ii, jj, kk (E,) host
        frame, target frame, patch. Returns (new state, flow revision (1, E, 2), confidence (1, E, 2))."""
        net = self.norm(net + inp + self.corr(corr))
        ix, jx = temporal_neighbors(kk, jj)
        mask_ix = (ix >= 0).to(net.dtype).reshape(1, -1, 1)
        mask_jx = (jx >= 0).to(net.dtype).reshape(1, -1, 1)
        net = net + self.c1(mask_ix * net[:, ix.clamp_min(0)])
        net = net + self.c2(mask_jx * net[:, jx.clamp_min(0)])
        net = net + self.agg_kk(net, kk)
        net = net + self.agg_ij(net, ii * 12345 + jj)
        net = self.gru(net)
        return net, self.d(net), self.w(net)


class DPVONet(nn.Module):
    """The networks of DPVO's VONet (the bundle adjustment is M3C's C++ patch BA)."""

    def __init__(self):
        super().__init__()
        self.patchify = Patchifier()
        self.update = Update()

    @torch.no_grad()
    def encode(self, images_bgr: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """uint8 images (N, H, W, 3) BGR, H and W multiples of 4 -> matching features (N, 128, H/4, W/4) and
        context features (N, 384, H/4, W/4)."""
        if images_bgr.ndim != 4 or images_bgr.shape[-1] != 3:
            raise ValueError(f"images must be (N, H, W, 3), got {tuple(images_bgr.shape)}")
        if images_bgr.shape[1] % RESOLUTION or images_bgr.shape[2] % RESOLUTION:
            raise ValueError(f"image sides must be multiples of {RESOLUTION}, got {tuple(images_bgr.shape[1:3])}")
        x = 2 * (images_bgr.permute(0, 3, 1, 2).float() / 255.0) - 0.5
        return self.patchify.fnet(x) / 4.0, self.patchify.inet(x) / 4.0


def sample(features: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of a feature map (C, H, W) at points (..., 2) x, y in its pixels (zero outside) ->
    (..., C)."""
    C, H, W = features.shape
    table = features.reshape(C, -1).T.contiguous()  # (H W, C): one row per pixel, gathered by index
    x, y = points[..., 0], points[..., 1]
    x0, y0 = torch.floor(x), torch.floor(y)
    out = 0
    for dx in (0, 1):
        for dy in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            w = (1 - (x - x0 - dx).abs()) * (1 - (y - y0 - dy).abs())
            inside = (xi >= 0) & (xi <= W - 1) & (yi >= 0) & (yi <= H - 1)
            flat = (yi.clamp(0, H - 1) * W + xi.clamp(0, W - 1)).long()
            out = out + (w * inside)[..., None] * table[flat]
    return out


def patch_features(fmap: torch.Tensor, imap: torch.Tensor, centres: torch.Tensor):
    """One frame's features (128, h, w), (384, h, w) and patch centres (M, 2) x, y at feature resolution ->
    matching patches (M, 128, 3, 3) and context (M, 384) (DPVO's patchify, bilinear)."""
    r = PATCH_SIZE // 2
    offsets = torch.arange(-r, r + 1, dtype=centres.dtype, device=centres.device)
    oy, ox = torch.meshgrid(offsets, offsets, indexing="ij")
    grid = centres[:, None, None, :] + torch.stack([ox, oy], dim=-1)  # (M, 3, 3, 2)
    return sample(fmap, grid).permute(0, 3, 1, 2), sample(imap, centres)


def _window_correlation(gmap: torch.Tensor, features: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """The kernel's two steps on one feature map (C, H, W): dot products of each patch pixel's features gmap
    (E, C, 3, 3) with the map on the (2R+2)^2 integer window from floor(points) (zero outside the map), then the
    bilinear blend of neighbouring entries by the points' fractions. points (E, 3, 3, 2) -> (E, 3, 3, 7 y, 7 x)."""
    C, H, W = features.shape
    table = features.reshape(C, -1).T.contiguous()  # (H W, C)
    steps = torch.arange(-RADIUS, RADIUS + 2, device=points.device)
    x0, y0 = torch.floor(points[..., 0]), torch.floor(points[..., 1])
    xi = x0.long()[..., None, None] + steps[None, :]  # (E, 3, 3, 1, 8)
    yi = y0.long()[..., None, None] + steps[:, None]  # (E, 3, 3, 8, 1)
    inside = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)
    flat = yi.clamp(0, H - 1) * W + xi.clamp(0, W - 1)  # (E, 3, 3, 8, 8)
    corr = torch.einsum("epqabc,ecpq->epqab", table[flat], gmap) * inside
    dx = (points[..., 0] - x0)[..., None, None]
    dy = (points[..., 1] - y0)[..., None, None]
    return ((1 - dx) * (1 - dy) * corr[..., :-1, :-1] + dx * (1 - dy) * corr[..., :-1, 1:]
            + (1 - dx) * dy * corr[..., 1:, :-1] + dx * dy * corr[..., 1:, 1:])


def correlation(gmap: torch.Tensor, fmap: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Edges' matching patches gmap (E, 128, 3, 3), the target frames' features fmap (E, 128, h, w) or one map
    (128, h, w) shared by all edges, and each patch pixel's position in the target coords (E, 3, 3, 2) x, y at
    feature resolution -> (E, 882) correlation features in DPVO's order."""
    maps = fmap if fmap.ndim == 4 else fmap[None]
    E = gmap.shape[0]
    levels = []
    for level in LEVELS:
        pooled = F.avg_pool2d(maps, level, stride=level) if level > 1 else maps
        points = coords / level
        if len(pooled) == 1:  # one target for every edge: a chunk of edges at a time
            parts = [_window_correlation(gmap[s:s + CHUNK], pooled[0], points[s:s + CHUNK])
                     for s in range(0, E, CHUNK)]
        else:
            parts = [_window_correlation(gmap[e:e + 1], pooled[e], points[e:e + 1]) for e in range(E)]
        corr = torch.cat(parts) if parts else coords.new_zeros((0, 3, 3, 7, 7))  # (E, row, col, y-off, x-off)
        levels.append(corr.permute(0, 4, 3, 1, 2))  # (E, x-offset, y-offset, row, col)
    return torch.stack(levels, dim=-1).reshape(E, -1)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def load_dpvo(path: str | os.PathLike | None = None) -> DPVONet:
    """DPVO's networks from the official dpvo.pth ('module.' prefixes stripped, update.lmbda dropped, as DPVO's
    load_weights does). path None -> $M3C_MODELS/dpvo/dpvo.pth. Eval mode."""
    file = ckpt.resolve_path(path, DPVO_SOURCE)
    raw = ckpt.read_checkpoint(file, DPVO_SOURCE)
    state = ckpt.strip_prefix(ckpt.take_state_dict(raw, ("state_dict", "model", ""), file, DPVO_SOURCE), "module.")
    model = DPVONet()
    ckpt.load_into(model, state, file, DPVO_SOURCE, ignore_prefixes=("update.lmbda",))
    return model.eval()


__all__ = ["CORR_DIM", "DPVONet", "DPVO_SOURCE", "Update", "correlation", "load_dpvo", "patch_features", "sample",
           "temporal_neighbors"]
