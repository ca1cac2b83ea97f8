"""VPoser (Pavlakos et al. 2019; human_body_prior), the VAE pose prior over SMPL's 21 body joints, versions 1
and 2, in torch with their official state-dict layouts.

Both encode a body pose (21 x 3 axis-angle) to a 32-d Gaussian N(mean, scale^2) with scale = softplus(.), and
decode a latent to 21 rotation matrices through VPoser's 6D representation (column Gram-Schmidt).
    v1 (HuMoR, SLAHMR): encoder BN(63) fc1 LReLU(0.2) BN(512) [dropout] fc2 LReLU(0.2) mu|logvar;
        decoder fc1 LReLU(0.2) [dropout] fc2 LReLU(0.2) out(126). File: a plain state dict (.pt).
    v2 (V02_05): encoder BN(63) Linear LReLU(0.01) BN(512) [dropout] Linear Linear mu|logvar;
        decoder Linear LReLU(0.01) [dropout] Linear LReLU(0.01) Linear(126). File: a Lightning .ckpt whose
        'state_dict' keys carry the prefix 'vp_model.'.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from m3c.models import checkpoint as ckpt
from m3c.models.rotations import matrix_to_axis_angle, rotation_6d_to_matrix_columns

NUM_JOINTS = 21
LATENT_DIM = 32
HIDDEN = 512

VPOSER_V1_SOURCE = ckpt.CheckpointSource(
    model="VPoser v1",
    default_path="vposer_v1_0",
    obtain=("register at https://smpl-x.is.tue.mpg.de and download VPoser v1.0 (folder vposer_v1_0, the file "
            "is snapshots/TR00_E096.pt: a plain state dict with bodyprior_enc_* / bodyprior_dec_* keys); pass "
            "the folder or the .pt file."),
)
VPOSER_V2_SOURCE = ckpt.CheckpointSource(
    model="VPoser v2",
    default_path="V02_05",
    obtain=("register at https://smpl-x.is.tue.mpg.de and download VPoser v2.0 (folder V02_05, the file is "
            "snapshots/V02_05_epoch=*.ckpt: a Lightning checkpoint whose 'state_dict' keys start with "
            "'vp_model.'); pass the folder or the .ckpt file."),
)


def _flat_pose(pose_body: torch.Tensor) -> torch.Tensor:
    if pose_body.shape[-1] == 3 * NUM_JOINTS:
        return pose_body.reshape(-1, 3 * NUM_JOINTS)
    if pose_body.shape[-2:] == (NUM_JOINTS, 3):
        return pose_body.reshape(-1, 3 * NUM_JOINTS)
    raise ValueError(f"pose_body must have shape (B, 21, 3) or (B, 63), got {tuple(pose_body.shape)}")


class VPoserV1(nn.Module):
    """VPoser v1.0; attribute names are the checkpoint's keys."""

    version = "v1"
    leaky_slope = 0.2

    def __init__(self, hidden: int = HIDDEN, latent_dim: int = LATENT_DIM):
        super().__init__()
        n = 3 * NUM_JOINTS
        self.bodyprior_enc_bn1 = nn.BatchNorm1d(n)
        self.bodyprior_enc_fc1 = nn.Linear(n, hidden)
        self.bodyprior_enc_bn2 = nn.BatchNorm1d(hidden)
        self.bodyprior_enc_fc2 = nn.Linear(hidden, hidden)
        self.bodyprior_enc_mu = nn.Linear(hidden, latent_dim)
        self.bodyprior_enc_logvar = nn.Linear(hidden, latent_dim)
        self.dropout = nn.Dropout(0.1)
        self.bodyprior_dec_fc1 = nn.Linear(latent_dim, hidden)
        self.bodyprior_dec_fc2 = nn.Linear(hidden, hidden)
        self.bodyprior_dec_out = nn.Linear(hidden, 6 * NUM_JOINTS)

    def encode(self, pose_body: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """pose_body (B, 21, 3) / (B, 63) axis-angle -> (mean (B, 32), scale (B, 32))."""
        h = self.bodyprior_enc_bn1(_flat_pose(pose_body))
        h = F.leaky_relu(self.bodyprior_enc_fc1(h), self.leaky_slope)
        h = self.dropout(self.bodyprior_enc_bn2(h))
        h = F.leaky_relu(self.bodyprior_enc_fc2(h), self.leaky_slope)
        return self.bodyprior_enc_mu(h), F.softplus(self.bodyprior_enc_logvar(h))

    def decode_6d(self, z: torch.Tensor) -> torch.Tensor:
        """z (B, 32) -> the raw 6D output (B, 126)."""
        h = F.leaky_relu(self.bodyprior_dec_fc1(z), self.leaky_slope)
        h = F.leaky_relu(self.bodyprior_dec_fc2(self.dropout(h)), self.leaky_slope)
        return self.bodyprior_dec_out(h)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (B, 32) -> body joint rotations (B, 21, 3, 3)."""
        return rotation_6d_to_matrix_columns(self.decode_6d(z).reshape(-1, NUM_JOINTS, 6))

    def decode_axis_angle(self, z: torch.Tensor) -> torch.Tensor:
        """z (B, 32) -> body pose (B, 21, 3) axis-angle."""
        return matrix_to_axis_angle(self.decode(z))


class _Flatten(nn.Module):
    def forward(self, x):
        return x.reshape(x.shape[0], -1)


class _NormalHead(nn.Module):
    def __init__(self, hidden: int, latent_dim: int):
        super().__init__()
        self.mu = nn.Linear(hidden, latent_dim)
        self.logvar = nn.Linear(hidden, latent_dim)

    def forward(self, h):
        return self.mu(h), F.softplus(self.logvar(h))


class _Rotation6d(nn.Module):
    def forward(self, x):
        return rotation_6d_to_matrix_columns(x.reshape(x.shape[0], NUM_JOINTS, 6))


class VPoserV2(nn.Module):
    """VPoser v2.0 (V02_05); module indices are the checkpoint's keys (encoder_net.2 = first Linear, ...)."""

    version = "v2"
    leaky_slope = 0.01

    def __init__(self, hidden: int = HIDDEN, latent_dim: int = LATENT_DIM):
        super().__init__()
        n = 3 * NUM_JOINTS
        self.encoder_net = nn.Sequential(
            _Flatten(), nn.BatchNorm1d(n), nn.Linear(n, hidden), nn.LeakyReLU(self.leaky_slope),
            nn.BatchNorm1d(hidden), nn.Dropout(0.1), nn.Linear(hidden, hidden), nn.Linear(hidden, hidden),
            _NormalHead(hidden, latent_dim))
        self.decoder_net = nn.Sequential(
            nn.Linear(latent_dim, hidden), nn.LeakyReLU(self.leaky_slope), nn.Dropout(0.1),
            nn.Linear(hidden, hidden), nn.LeakyReLU(self.leaky_slope), nn.Linear(hidden, 6 * NUM_JOINTS),
            _Rotation6d())

    def encode(self, pose_body: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """pose_body (B, 21, 3) / (B, 63) axis-angle -> (mean (B, 32), scale (B, 32))."""
        return self.encoder_net(_flat_pose(pose_body))

    def decode_6d(self, z: torch.Tensor) -> torch.Tensor:
        """z (B, 32) -> the raw 6D output (B, 126)."""
        return self.decoder_net[:-1](z)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (B, 32) -> body joint rotations (B, 21, 3, 3)."""
        return self.decoder_net(z)

    def decode_axis_angle(self, z: torch.Tensor) -> torch.Tensor:
        return matrix_to_axis_angle(self.decode(z))


VPoser = VPoserV1 | VPoserV2


def _pick_file(path: Path, version: str) -> Path:
    if not path.is_dir():
        return path
    source = VPOSER_V1_SOURCE if version == "v1" else VPOSER_V2_SOURCE
    folder = path / "snapshots" if (path / "snapshots").is_dir() else path
    return ckpt.newest_file(folder, "*.pt" if version == "v1" else "*.ckpt", source)


def _guess_version(path: Path) -> str:
    if path.is_dir():
        folder = path / "snapshots" if (path / "snapshots").is_dir() else path
        return "v2" if any(folder.glob("*.ckpt")) else "v1"
    return "v2" if path.suffix == ".ckpt" else "v1"


def load_vposer(path: str | os.PathLike | None = None, version: str | None = None,
                dtype: torch.dtype = torch.float32) -> VPoserV1 | VPoserV2:
    """VPoser from its official files, in eval mode.

    path: the experiment folder (vposer_v1_0 / V02_05; the newest snapshot is used, as the originals do) or
    the snapshot file; None -> $M3C_MODELS/vposer_v1_0 (or V02_05 with version='v2').
    version: 'v1', 'v2' or None to infer it from the file type (.pt -> v1, .ckpt -> v2).
    """
    if version not in (None, "v1", "v2"):
        raise ValueError(f"version must be 'v1', 'v2' or None, got {version!r}")
    if path is None:
        version = version or "v1"
    source = VPOSER_V2_SOURCE if version == "v2" else VPOSER_V1_SOURCE
    located = ckpt.resolve_path(path, source)
    version = version or _guess_version(located)
    source = VPOSER_V2_SOURCE if version == "v2" else VPOSER_V1_SOURCE
    file = _pick_file(located, version)
    raw = ckpt.read_checkpoint(file, source)
    if version == "v1":
        model: VPoserV1 | VPoserV2 = VPoserV1()
        state = ckpt.take_state_dict(raw, ("", "state_dict", "model"), file, source)
    else:
        model = VPoserV2()
        state = ckpt.strip_prefix(ckpt.take_state_dict(raw, ("state_dict", ""), file, source), "vp_model.")
        # Lightning files also hold the training body model; like the original, keep only VPoser's own keys.
        state = {k: v for k, v in state.items() if k.startswith(("encoder_net.", "decoder_net."))}
    model = model.to(dtype)
    ckpt.load_into(model, state, file, source, optional_suffixes=("num_batches_tracked",))
    return model.eval()


__all__ = ["VPoserV1", "VPoserV2", "VPoser", "load_vposer", "NUM_JOINTS", "LATENT_DIM"]
