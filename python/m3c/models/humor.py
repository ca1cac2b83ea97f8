"""HuMoR (Rempe et al. 2021), the conditional-VAE motion prior, in torch with its official state-dict layout.

Three GroupNorm MLPs over 339-d states (see m3c.models.humor_state) and a 48-d latent transition z:
    posterior encoder  q(z | x_prev, x_next): [678, 1024, 1024, 1024, 1024, 96] -> mean, log-variance
    conditional prior  p(z | x_prev):         [339, 1024, 1024, 1024, 1024, 96] -> mean, log-variance
    decoder            x_next = f(x_prev, z): [387, 1024, 1024, 512, 216], z re-concatenated before every
                                              Linear but the first; outputs changes + 9 contact logits
All inputs are in the canonical frame of x_prev.

Motion-prior terms (negative log-likelihoods, summed over the 48 latent dimensions):
    latent_nll(z, x_prev)          = -log N(z; mu_p(x_prev), sigma_p(x_prev)^2)
                                     (HuMoR's test-time fitting and SLAHMR optimise z with this term)
    transition_nll(x_prev, x_next) = latent_nll(mu_q(x_prev, x_next), x_prev)
                                     (the seed thesis scores each consecutive pair of optimised states: the
                                     posterior mean of the pair under the conditional prior)
Both take states in the ground frame and canonicalise them first, so gradients reach the world states.
"""

from __future__ import annotations

import math
import os

import torch
from torch import nn

from m3c.models import checkpoint as ckpt
from m3c.models import humor_state as hs

LOG_2PI = math.log(2 * math.pi)
ENCODER_LAYERS = (2 * hs.STATE_DIM, 1024, 1024, 1024, 1024, 2 * hs.LATENT_DIM)
PRIOR_LAYERS = (hs.STATE_DIM, 1024, 1024, 1024, 1024, 2 * hs.LATENT_DIM)
DECODER_LAYERS = (hs.STATE_DIM + hs.LATENT_DIM, 1024, 1024, 512, hs.DECODER_OUTPUT_DIM)
GROUP_NORM_GROUPS = 16
GROUP_NORM_EPS = 1e-5

HUMOR_SOURCE = ckpt.CheckpointSource(
    model="HuMoR",
    default_path="humor/best_model.pth",
    obtain=("download checkpoints.zip from http://download.cs.stanford.edu/orion/humor/checkpoints.zip (the "
            "HuMoR repository's get_ckpt.sh, github.com/davrempe/humor) and use checkpoints/humor/best_model.pth "
            "(a torch file: dict with 'model' -> state dict)."),
)


class GroupNormMLP(nn.Module):
    """HuMoR's MLP: Linear(sizes[0], sizes[1]), then for each further size [GroupNorm(16) -> ReLU ->
    Linear(prev + skip, next)]. With skip_dim > 0 the last skip_dim input features are concatenated after
    the hidden features before every Linear but the first.

    Module indices in `net` (the checkpoint's keys): Linear 0, 3, 6, ...; GroupNorm 1, 4, ...; ReLU 2, 5, ...
    """

    def __init__(self, sizes, skip_dim: int = 0, groups: int = GROUP_NORM_GROUPS):
        super().__init__()
        self.sizes = tuple(int(s) for s in sizes)
        self.skip_dim = int(skip_dim)
        layers: list[nn.Module] = [nn.Linear(self.sizes[0], self.sizes[1])]
        for width, out in zip(self.sizes[1:-1], self.sizes[2:]):
            layers += [nn.GroupNorm(groups, width, eps=GROUP_NORM_EPS), nn.ReLU(),
                       nn.Linear(width + self.skip_dim, out)]
        self.net = nn.ModuleList(layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, sizes[0]) -> (B, sizes[-1])."""
        skip = x[:, x.shape[1] - self.skip_dim:] if self.skip_dim else None
        h = x
        for i, layer in enumerate(self.net):
            if skip is not None and i > 0 and isinstance(layer, nn.Linear):
                h = torch.cat([h, skip], dim=1)
            h = layer(h)
        return h


class HumorModel(nn.Module):
    """HuMoR's encoder, conditional prior and decoder. Attribute names follow the official checkpoint."""

    def __init__(self):
        super().__init__()
        self.encoder = GroupNormMLP(ENCODER_LAYERS)
        self.prior_net = GroupNormMLP(PRIOR_LAYERS)
        self.decoder = GroupNormMLP(DECODER_LAYERS, skip_dim=hs.LATENT_DIM)

    def posterior(self, x_prev: torch.Tensor, x_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Canonical states (B, 339) x 2 -> (mean (B, 48), log-variance (B, 48))."""
        out = self.encoder(torch.cat([x_prev, x_next], dim=-1))
        return out[:, :hs.LATENT_DIM], out[:, hs.LATENT_DIM:]

    def prior(self, x_prev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Canonical state (B, 339) -> (mean (B, 48), log-variance (B, 48))."""
        out = self.prior_net(x_prev)
        return out[:, :hs.LATENT_DIM], out[:, hs.LATENT_DIM:]

    def decode(self, x_prev: torch.Tensor, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Canonical x_prev (B, 339), z (B, 48) -> (canonical x_next (B, 339), contact logits (B, 9))."""
        out = self.decoder(torch.cat([x_prev, z], dim=-1))
        return hs.apply_decoder_output(x_prev, out)

    def decode_world(self, x_prev: torch.Tensor, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One roll-out step in the ground frame: canonicalise x_prev, decode, map the result back."""
        frame = hs.canonical_frame(x_prev)
        x_next, contacts = self.decode(hs.to_canonical(x_prev, frame), z)
        return hs.from_canonical(x_next, frame), contacts


def gaussian_nll(z: torch.Tensor, mean: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """-log N(z; mean, exp(logvar)) summed over the last dim: sum 0.5 (logvar + log 2 pi + (z-mean)^2/var)."""
    return 0.5 * (logvar + LOG_2PI + (z - mean) ** 2 * torch.exp(-logvar)).sum(-1)


def latent_nll(model: HumorModel, z: torch.Tensor, x_prev: torch.Tensor, canonicalize: bool = True) -> torch.Tensor:
    """NLL of latent transitions z (B, 48) under the conditional prior of x_prev (B, 339). -> (B,)"""
    if canonicalize:
        x_prev = hs.to_canonical(x_prev, hs.canonical_frame(x_prev))
    mean, logvar = model.prior(x_prev)
    return gaussian_nll(z, mean, logvar)


def transition_nll(model: HumorModel, x_prev: torch.Tensor, x_next: torch.Tensor,
                   canonicalize: bool = True) -> torch.Tensor:
    """NLL of the posterior mean of each transition x_prev -> x_next (B, 339 each) under the prior. -> (B,)"""
    if canonicalize:
        x_prev, x_next = hs.canonicalize_pair(x_prev, x_next)
    z, _ = model.posterior(x_prev, x_next)
    mean, logvar = model.prior(x_prev)
    return gaussian_nll(z, mean, logvar)


def sequence_transition_nll(model: HumorModel, states: torch.Tensor) -> torch.Tensor:
    """Sum of transition_nll over consecutive pairs of a sequence of states (T, 339). -> scalar"""
    return transition_nll(model, states[:-1], states[1:]).sum()


def load_humor(path: str | os.PathLike | None = None, dtype: torch.dtype = torch.float32) -> HumorModel:
    """HuMoR from its official checkpoint (a torch dict with 'model'; a 'module.' prefix from DataParallel
    is stripped as the original does). path None -> $M3C_MODELS/humor/best_model.pth. Returns eval mode."""
    file = ckpt.resolve_path(path, HUMOR_SOURCE)
    if file.is_dir():
        file = ckpt.newest_file(file, "*.pth", HUMOR_SOURCE)
    raw = ckpt.read_checkpoint(file, HUMOR_SOURCE)
    state = ckpt.strip_prefix(ckpt.take_state_dict(raw, ("model", ""), file, HUMOR_SOURCE), "module.")
    model = HumorModel().to(dtype)
    # Body models the original can hold for SMPL-joint inputs are not part of the prior.
    ckpt.load_into(model, state, file, HUMOR_SOURCE, ignore_prefixes=("male_bm.", "female_bm.", "neutral_bm."))
    return model.eval()
