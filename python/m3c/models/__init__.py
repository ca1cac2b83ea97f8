"""Learned models in torch with loaders for their official checkpoints: HuMoR (motion prior), VPoser (pose
prior), the WHAM modules used for the world lift, and the patch networks ViTPose (2D keypoints) and HMR 2.0
(camera-local SMPL) on their shared ViT. No weights ship with M3C; see each loader's error for
where a checkpoint is obtained."""

from m3c.models.checkpoint import CheckpointError, CheckpointNotFoundError
from m3c.models.hmr2 import HMR2, load_hmr2
from m3c.models.humor import HumorModel, latent_nll, load_humor, transition_nll
from m3c.models.vposer import VPoserV1, VPoserV2, load_vposer
from m3c.models.vitpose import ViTPose, load_vitpose
from m3c.models.wham import WhamLifter, load_wham

__all__ = ["CheckpointError", "CheckpointNotFoundError", "HumorModel", "latent_nll", "load_humor",
           "transition_nll", "VPoserV1", "VPoserV2", "load_vposer",
           "WhamLifter", "load_wham", "HMR2", "load_hmr2", "ViTPose", "load_vitpose"]
