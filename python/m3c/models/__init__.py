"""Learned models in torch with loaders for their official checkpoints: HuMoR (motion prior), VPoser (pose
prior) and the WHAM modules used for the world lift. No weights ship with M3C; see each loader's error for
where a checkpoint is obtained."""

from m3c.models.checkpoint import CheckpointError, CheckpointNotFoundError
from m3c.models.humor import HumorModel, latent_nll, load_humor, transition_nll
from m3c.models.vposer import VPoserV1, VPoserV2, load_vposer
from m3c.models.wham import WhamLifter, load_wham

__all__ = ["CheckpointError", "CheckpointNotFoundError", "HumorModel", "latent_nll", "load_humor",
           "transition_nll", "VPoserV1", "VPoserV2", "load_vposer",
           "WhamLifter", "load_wham"]
