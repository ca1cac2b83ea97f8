"""The thesis's learned patch-level networks as estimators: ViTPose for COCO-17 keypoints (`vitpose`, pose2d) and
HMR 2.0 for camera-local bodies (`hmr2`, body), each reading a person's thesis patch (m3c.perception.boxes.
network_input: 5 px padding, square, shifted inside the frame, other people whitened except the person's own
mask) resized to its input. They need torch and the official checkpoints (m3c.models.load_vitpose / load_hmr2);
nothing is downloaded. Importing this module imports neither.
"""

from __future__ import annotations

import numpy as np

from m3c.camera import project
from m3c.perception.body import BodyFits
from m3c.perception.boxes import crop_to_full_camera, network_input
from m3c.perception.interfaces import BodyEstimator, PoseEstimator2D
from m3c.perception.mediapipe_pose import tight_box
from m3c.perception.registry import register
from m3c.perception.types import FrameContext, Person

VITPOSE = "vitpose"
HMR2 = "hmr2"


def import_torch():
    try:
        import torch
    except ImportError as err:
        raise ImportError("the ViTPose and HMR 2.0 estimators need torch: pip install 'm3c[torch]' (scripts/setup.sh "
                          "installs the CPU wheel)") from err
    return torch


def _inputs(ctx: FrameContext, people: list[Person], size: tuple[int, int], padding: float):
    """Each person's network input, isolated from every other person of the frame."""
    out = []
    for i, person in enumerate(people):
        others = np.array([p.box for j, p in enumerate(people) if j != i]).reshape(-1, 4)
        out.append(network_input(ctx.image, person.box, others, person.mask_in if person.mask is not None else None,
                                 size, padding))
    return out


def _batches(items: list, size: int):
    for start in range(0, len(items), size):
        yield items[start:start + size]


@register("pose2d", VITPOSE)
class ViTPoseEstimator(PoseEstimator2D):
    """ViTPose on each person's patch (widened to 256 x 192 with white margins), with flip test and DARK/UDP
    decoding; keypoint confidence = the heatmap maximum clipped to [0, 1]; the person's box becomes the tight box
    of its mask and its keypoints above min_confidence. checkpoint: the mmpose file (default
    $M3C_MODELS/vitpose/vitpose-h.pth)."""

    def __init__(self, checkpoint: str | None = None, padding: float = 5.0, flip_test: bool = True,
                 batch_size: int = 8, num_heads: int | None = None, min_confidence: float = 0.5,
                 device: str = "cpu"):
        import_torch()
        from m3c.models.vitpose import load_vitpose

        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.model = load_vitpose(checkpoint, num_heads).to(device)
        self.padding, self.flip_test, self.batch_size, self.device = padding, flip_test, batch_size, device
        self.min_confidence = min_confidence

    def keypoints(self, images: np.ndarray, geometries: list) -> np.ndarray:
        """Network inputs (B, 256, 192, 3) uint8 and their NetworkInput placements -> keypoints (B, 17, 3) u, v
        (frame pixels), confidence."""
        torch = import_torch()
        from m3c.models.vit import normalize_images
        from m3c.models.vitpose import decode_heatmaps, heatmap_to_frame

        x = normalize_images(torch.from_numpy(np.ascontiguousarray(images))).to(self.device)
        heatmaps = self.model.heatmaps(x, self.flip_test).cpu().numpy()
        coords, scores = decode_heatmaps(heatmaps)
        size = self.model.backbone.config.image_size
        out = np.empty(coords.shape[:2] + (3,))
        for b, g in enumerate(geometries):
            out[b, :, :2] = heatmap_to_frame(coords[b], g, size, heatmaps.shape[2:])
        out[..., 2] = np.clip(scores, 0.0, 1.0)
        return out

    def estimate(self, ctx: FrameContext, people: list[Person]) -> list[Person | None]:
        if not people:
            return []
        inputs = _inputs(ctx, people, self.model.backbone.config.image_size, self.padding)
        keypoints = []
        for chunk in _batches(inputs, self.batch_size):
            keypoints.extend(self.keypoints(np.stack([c.image for c in chunk]), chunk))
        out = []
        for person, kp in zip(people, keypoints):
            sources = dict(person.sources)
            sources["pose2d"] = VITPOSE
            # The person's tight box from the mask and the confident keypoints: a tracker's proposal box is wider
            # than the person and must not be handed on as the observation.
            box = tight_box(kp, person.mask, person.mask_box, ctx.size, self.min_confidence)
            out.append(Person(person.box if box is None else box, person.score, kp, None, person.mask,
                              person.mask_box, sources))
        return out

    def close(self) -> None:
        self.model = None


@register("body", HMR2)
class HMR2Estimator(BodyEstimator):
    """HMR 2.0 on each person's square patch (256 x 256): SMPL pose and betas per frame, the crop camera placed in
    the full image (crop_to_full_camera). The result is in SMPL's parameters; with M3C's open body model (the
    default) poses carry over, betas do not (its shape space is its own). checkpoint: the Lightning file
    (default $M3C_MODELS/hmr2/checkpoints/epoch=35-step=1000000.ckpt), config: its model_config.yaml."""

    reads_images = True

    def __init__(self, checkpoint: str | None = None, config: str | None = None, model_path: str | None = None,
                 padding: float = 5.0, batch_size: int = 8, backbone_heads: int | None = None,
                 min_confidence: float = 0.3, device: str = "cpu"):
        import_torch()
        from m3c.body import BodyModel, default_body_model
        from m3c.models.hmr2 import load_hmr2

        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.network = load_hmr2(checkpoint, config, backbone_heads).to(device)
        self.model = BodyModel.from_file(model_path, smpl_layout=True) if model_path else default_body_model()
        self.padding, self.batch_size, self.device = padding, batch_size, device
        self.min_confidence = min_confidence

    def regress(self, images: np.ndarray) -> dict:
        """Network inputs (B, 256, 256, 3) uint8 -> pose (B, 24, 3) axis-angle, betas (B, 10), crop_cam (B, 3)."""
        torch = import_torch()
        from m3c.models.vit import normalize_images

        x = normalize_images(torch.from_numpy(np.ascontiguousarray(images))).to(self.device)
        with torch.no_grad():
            out = self.network(x)
        return {"pose": out.pose.double().cpu().numpy(), "betas": out.betas.double().cpu().numpy(),
                "crop_cam": out.crop_cam.double().cpu().numpy()}

    def observe(self, ctx: FrameContext, people: list[Person]) -> list:
        from m3c.models.hmr2 import IMAGE_SIZE

        if not people:
            return []
        inputs = _inputs(ctx, people, (IMAGE_SIZE, IMAGE_SIZE), self.padding)
        results = []
        for chunk in _batches(inputs, self.batch_size):
            r = self.regress(np.stack([c.image for c in chunk]))
            for b, c in enumerate(chunk):
                results.append({"pose": r["pose"][b], "betas": r["betas"][b], "crop_cam": r["crop_cam"][b],
                                "region": c.region})
        return results

    def fit_track(self, keypoints, keypoints3d, intrinsics, restart=None, times=None,
                  observations=None) -> BodyFits:
        from m3c.perception.body import keypoint_regressor

        keypoints = np.asarray(keypoints, dtype=np.float64)
        n, K = keypoints.shape[:2]
        if observations is None or len(observations) != n:
            raise ValueError(f"the hmr2 body estimator needs one observation per frame ({n}), got "
                             f"{None if observations is None else len(observations)}")
        B = self.model.num_betas
        pose, betas, transl = np.zeros((n, 24, 3)), np.zeros((n, B)), np.zeros((n, 3))
        status = ["ok" if o is not None else "no_image_regression" for o in observations]
        K_all = np.broadcast_to(np.asarray(intrinsics, dtype=np.float64).reshape(-1, 4), (n, 4))
        for i, o in enumerate(observations):
            if o is None:
                continue
            pose[i] = o["pose"]
            m = min(B, len(o["betas"]))
            betas[i, :m] = o["betas"][:m]
            if not np.isfinite(o["crop_cam"]).all() or o["crop_cam"][0] <= 0:
                status[i] = "bad_camera"  # a weak-perspective scale <= 0 puts the body behind the camera
                continue
            transl[i] = crop_to_full_camera(o["crop_cam"], o["region"], K_all[i])[0]
        valid = np.array([s == "ok" for s in status])
        errors = np.full((n, K), np.nan)
        if valid.any():
            points = self.model.keypoints(keypoint_regressor(self.model, K), pose[valid], betas[valid], transl[valid])
            uv = project(points, K_all[valid][:, None])
            errors[valid] = np.linalg.norm(uv - keypoints[valid, :, :2], axis=-1)
        seen = (keypoints[..., 2] >= self.min_confidence) & valid[:, None]
        errors = np.where(seen, errors, 0.0)
        counts = seen.sum(axis=1)
        mean = np.where(counts > 0, errors.sum(axis=1) / np.maximum(counts, 1), np.nan)
        return BodyFits(transl, pose[:, 0], pose[:, 1:], betas, mean, errors, counts, np.zeros(n, dtype=bool), status)

    def close(self) -> None:
        self.network = None


__all__ = ["HMR2Estimator", "ViTPoseEstimator"]
