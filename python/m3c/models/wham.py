"""The WHAM modules (Shin et al. 2024) used for the world lift, in torch with the official checkpoint layout.

Per frame the network reads 17 COCO keypoints normalised to the person's square box ([-1, 1] across the box)
and the box (centre and side relative to the image): 37 values; keypoints with confidence < 0.3 are replaced
by a learnt mask embedding. With d = 512 and a context of d + 51 = 563:
    motion_encoder      Linear 37 -> 512; LSTM(563, 512, 3) run frame by frame, fed its own previous 3D
                        keypoints (51); context = [LSTM output | 3D keypoints]          -> (B, F, 563)
    trajectory_decoder  LSTM(563 + 12, 563, 3) frame by frame, fed the previous root orientation (6D) and the
                        camera's angular velocity (6): root velocity (3, in the previous root frame) and
                        world root orientation (6D)
    integrator          MLP [563 + image feature 1024] -> 1024 -> 1024 -> 563, residual
    motion_decoder      LSTM(563 + 144, 563, 3): camera-frame pose (24 x 6D), betas, weak camera, 4 contacts
    trajectory_refiner  LSTM(563 + 12 + 9, 512, 2) over the whole sequence: corrections of root orientation and
                        velocity from the contact-masked foot velocities
World translation: v_world[t] = R_root[t-1] v[t], trans = cumsum (rollout_global_motion). 6D rotations are
WHAM's row layout (m3c.models.rotations.rotation_6d_to_matrix_rows). WHAM's world frame is y-down.
"""

from __future__ import annotations

import os

import torch
from torch import nn

from m3c.models import checkpoint as ckpt
from m3c.models.rotations import matrix_to_rotation_6d_rows, rotation_6d_to_matrix_rows

NUM_KEYPOINTS = 17
INPUT_DIM = 2 * NUM_KEYPOINTS + 3  # 37
EMBED_DIM = 512
CONTEXT_DIM = EMBED_DIM + 3 * NUM_KEYPOINTS  # 563
IMAGE_FEATURE_DIM = 1024  # ViT (HMR2.0) features; WHAM's ResNet variant uses 2048
NUM_LAYERS = 3
MASK_CONFIDENCE = 0.3
# SMPL joints whose initial 6D rotations seed the motion decoder's LSTM state.
MAIN_JOINTS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21)
IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)

WHAM_SOURCE = ckpt.CheckpointSource(
    model="WHAM",
    default_path="wham/wham_vit_w_3dpw.pth.tar",
    obtain=("run the WHAM repository's fetch_demo_data.sh (github.com/yohanshin/WHAM; Google Drive links in its "
            "README) and use checkpoints/wham_vit_w_3dpw.pth.tar (a torch dict with 'model' -> state dict)."),
)


class Regressor(nn.Module):
    """LSTM over [x | inits...] followed by one Linear head per output (WHAM's Regressor)."""

    def __init__(self, in_dim: int, hidden: int, out_dims, init_dim: int, num_layers: int):
        super().__init__()
        self.rnn = nn.LSTM(in_dim + init_dim, hidden, num_layers, batch_first=True, dropout=0.3)
        self.num_outputs = len(out_dims)
        for i, out in enumerate(out_dims):
            setattr(self, f"declayer{i}", nn.Linear(hidden, out))

    def forward(self, x, inits, state=None):
        """x (B, S, in), inits: tensors (B, S, .) concatenated to x; state: (h, c) or None.
        Returns ([outputs (B, S, out_i)], LSTM output (B, S, hidden), new state)."""
        h, state = self.rnn(torch.cat([x, *inits], dim=-1), state)
        return [getattr(self, f"declayer{i}")(h) for i in range(self.num_outputs)], h, state


class NeuralInitialization(nn.Module):
    """MLP that turns an initial observation into the LSTM's (h0, c0), each (layers, B, hidden)."""

    def __init__(self, in_dim: int, hidden: int, num_layers: int):
        super().__init__()
        self.num_layers = num_layers
        self.linear1 = nn.Linear(in_dim, hidden)
        self.linear2 = nn.Linear(hidden, hidden * num_layers)
        self.linear3 = nn.Linear(hidden * num_layers, 2 * hidden * num_layers)
        self.relu1 = nn.ReLU()
        self.relu2 = nn.ReLU()

    def forward(self, x):
        """x (B, 1, in) -> (h0, c0)."""
        b = x.shape[0]
        out = self.linear3(self.relu2(self.linear2(self.relu1(self.linear1(x)))))
        out = out.reshape(b, 2, self.num_layers, -1).permute(1, 2, 0, 3).contiguous()
        return out[0], out[1]


class MotionEncoder(nn.Module):
    def __init__(self, in_dim: int = INPUT_DIM, d_embed: int = EMBED_DIM, num_layers: int = NUM_LAYERS,
                 num_keypoints: int = NUM_KEYPOINTS, dropout: float = 0.15):
        super().__init__()
        self.num_keypoints = num_keypoints
        self.embed_layer = nn.Linear(in_dim, d_embed)
        self.pos_drop = nn.Dropout(dropout)
        self.neural_init = NeuralInitialization(3 * num_keypoints + in_dim, d_embed, num_layers)
        self.regressor = Regressor(d_embed, d_embed, [3 * num_keypoints], 3 * num_keypoints, num_layers)

    def forward(self, x, init):
        """x (B, F, 37) normalised inputs; init (B, 1, 51 + 37): the first frame's root-centred 3D keypoints and
        its input. Returns (3D keypoints (B, F, 17, 3), motion context (B, F, 563))."""
        b, f = x.shape[:2]
        x = self.pos_drop(self.embed_layer(x))
        state = self.neural_init(init)
        previous = init[..., :3 * self.num_keypoints]
        keypoints, context = [], []
        for i in range(f):  # autoregressive: each frame sees the keypoints predicted for the one before
            (previous,), h, state = self.regressor(x[:, i:i + 1], [previous], state)
            keypoints.append(previous)
            context.append(h)
        keypoints = torch.cat(keypoints, dim=1)
        context = torch.cat([torch.cat(context, dim=1), keypoints], dim=-1)
        return keypoints.reshape(b, f, self.num_keypoints, 3), context


def compose_root(previous_6d, change_6d):
    """The residual root orientation: previous R[t-1] times the change read from change_6d + 6D(I), on the
    right (the change in the previous root's own frame, which the camera-frame inputs determine; the world
    heading does not enter). A zero change_6d holds R[t-1]. (..., 6) -> (..., 6)."""
    change = rotation_6d_to_matrix_rows(change_6d + change_6d.new_tensor(IDENTITY_6D))
    return matrix_to_rotation_6d_rows(rotation_6d_to_matrix_rows(previous_6d) @ change)


class TrajectoryDecoder(nn.Module):
    # True only in M3C's own regressor (m3c.training.regressor, flagged in its checkpoint): the orientation
    # head's 6D is a change from the previous orientation (compose_root). WHAM's own: the orientation itself.
    residual = False

    def __init__(self, d_context: int = CONTEXT_DIM, num_layers: int = NUM_LAYERS):
        super().__init__()
        self.regressor = Regressor(d_context, d_context, [3, 6], 12, num_layers)

    def forward(self, context, init_root, cam_angvel):
        """context (B, F, 563); init_root (B, 1, 6) world root orientation of frame 0 (6D rows); cam_angvel
        (B, F, 6). Returns (root orientations (B, F + 1, 6) including init_root, root velocities (B, F, 3))."""
        roots, velocities, state = [init_root], [], None
        for i in range(context.shape[1]):
            (velocity, root), _, state = self.regressor(context[:, i:i + 1], [roots[-1], cam_angvel[:, i:i + 1]],
                                                        state)
            if self.residual:
                root = compose_root(roots[-1], root)
            roots.append(root)
            velocities.append(velocity)
        return torch.cat(roots, dim=1), torch.cat(velocities, dim=1)


class Integrator(nn.Module):
    def __init__(self, in_channels: int = CONTEXT_DIM + IMAGE_FEATURE_DIM, out_channels: int = CONTEXT_DIM,
                 hidden: int = 1024):
        super().__init__()
        self.layer1 = nn.Linear(in_channels, hidden)
        self.relu1 = nn.ReLU()
        self.dr1 = nn.Dropout(0.1)
        self.layer2 = nn.Linear(hidden, hidden)
        self.relu2 = nn.ReLU()
        self.dr2 = nn.Dropout(0.1)
        self.layer3 = nn.Linear(hidden, out_channels)

    def forward(self, context, features):
        """context (B, F, 563), image features (B, F, 1024) -> (B, F, 563). The residual to the context is added
        only for sequences whose features are all non-zero (as in WHAM: zero features mean 'none')."""
        out = self.layer3(self.dr2(self.relu2(self.layer2(self.dr1(self.relu1(self.layer1(
            torch.cat([context, features], dim=-1))))))))
        has_features = (features != 0).all(dim=-1).all(dim=-1)
        return torch.where(has_features[:, None, None], out + context, out)


class MotionDecoder(nn.Module):
    """The camera-frame SMPL decoder (pose 24 x 6D, betas 10, weak camera 3, foot contacts 4)."""

    def __init__(self, d_context: int = CONTEXT_DIM, num_layers: int = NUM_LAYERS):
        super().__init__()
        self.neural_init = NeuralInitialization(6 * len(MAIN_JOINTS), d_context, num_layers)
        self.regressor = Regressor(d_context, d_context, [24 * 6, 10, 3, 4], 24 * 6, num_layers)

    def forward(self, context, init_pose):
        """context (B, F, 563); init_pose (B, 1, 24, 6) the first frame's camera-frame pose (6D rows).
        Returns pose (B, F, 144), betas (B, F, 10), camera (B, F, 3), contact logits (B, F, 4)."""
        b = context.shape[0]
        state = self.neural_init(init_pose[:, :, list(MAIN_JOINTS)].reshape(b, 1, -1))
        previous = init_pose.reshape(b, 1, -1)
        outputs = []
        for i in range(context.shape[1]):
            step, _, state = self.regressor(context[:, i:i + 1], [previous], state)
            previous = step[0]
            outputs.append(step)
        return tuple(torch.cat([o[k] for o in outputs], dim=1) for k in range(4))


class TrajectoryRefiner(nn.Module):
    def __init__(self, d_context: int = CONTEXT_DIM, hidden: int = EMBED_DIM, num_layers: int = 2):
        super().__init__()
        self.refiner = Regressor(d_context + 12, hidden, [6, 3], 9, num_layers)

    def forward(self, context, root, velocity, feet_world, contact, fps_scale: float = 30.0):
        """context (B, F, 563); root (B, F + 1, 6) and velocity (B, F, 3) from the trajectory decoder;
        feet_world (B, F, 4, 3) foot positions in the world; contact (B, F, 4) contact probabilities.
        Foot velocities (per frame, times 30 as in WHAM) masked by contact are the extra input.
        Returns refined (root (B, F + 1, 6), velocity (B, F, 3))."""
        b, f = context.shape[:2]
        feet_velocity = torch.cat([torch.zeros_like(feet_world[:, :1]), feet_world[:, 1:] - feet_world[:, :-1]],
                                  dim=1) * fps_scale
        feet_input = (feet_velocity * contact[..., None]).reshape(b, f, -1)
        (delta_root, delta_velocity), _, _ = self.refiner(torch.cat([context, feet_input], dim=-1),
                                                          [root[:, 1:], velocity])
        refined_root = torch.cat([root[:, :1], root[:, 1:] + delta_root], dim=1)
        return refined_root, velocity + delta_velocity


class WhamLifter(nn.Module):
    """The WHAM network's modules under their official names (the checkpoint's top-level keys)."""

    def __init__(self, image_feature_dim: int = IMAGE_FEATURE_DIM):
        super().__init__()
        self.mask_embedding = nn.Parameter(torch.zeros(1, 1, NUM_KEYPOINTS, 2))
        self.motion_encoder = MotionEncoder()
        self.trajectory_decoder = TrajectoryDecoder()
        self.integrator = Integrator(CONTEXT_DIM + image_feature_dim)
        self.motion_decoder = MotionDecoder()
        self.trajectory_refiner = TrajectoryRefiner()

    def masked_input(self, x, mask):
        """x (B, F, 37), mask (B, F, 17) True where a keypoint is unreliable: its two values are replaced by the
        learnt embedding (the box values are never masked)."""
        b, f = x.shape[:2]
        keep = (~mask)[..., None].to(x.dtype).expand(b, f, NUM_KEYPOINTS, 2)
        embedding = self.mask_embedding * mask[..., None].to(x.dtype)
        keypoints = x[..., :2 * NUM_KEYPOINTS].reshape(b, f, NUM_KEYPOINTS, 2) * keep + embedding
        return torch.cat([keypoints.reshape(b, f, -1), x[..., 2 * NUM_KEYPOINTS:]], dim=-1)

    def lift(self, x, mask, init_kp, init_root, cam_angvel):
        """Stages 1-2 of WHAM: the world trajectory from 2D keypoints and camera rotation.

        x (B, F, 37), mask (B, F, 17), init_kp (B, 1, 88), init_root (B, 1, 6), cam_angvel (B, F, 6).
        Returns a dict: keypoints_3d (B, F, 17, 3), context (B, F, 563), root_6d (B, F + 1, 6),
        velocity (B, F, 3), root_world (B, F, 3, 3), trans_world (B, F, 3).
        """
        keypoints, context = self.motion_encoder(self.masked_input(x, mask), init_kp)
        root, velocity = self.trajectory_decoder(context, init_root, cam_angvel)
        root_world, trans_world = rollout_global_motion(root, velocity)
        return {"keypoints_3d": keypoints, "context": context, "root_6d": root, "velocity": velocity,
                "root_world": root_world, "trans_world": trans_world}

    def refine(self, lifted: dict, feet_world, contact) -> dict:
        """The trajectory refiner applied to lift()'s output; feet_world (B, F, 4, 3), contact (B, F, 4)."""
        root, velocity = self.trajectory_refiner(lifted["context"], lifted["root_6d"], lifted["velocity"],
                                                 feet_world, contact)
        root_world, trans_world = rollout_global_motion(root, velocity)
        return dict(lifted, root_6d=root, velocity=velocity, root_world=root_world, trans_world=trans_world)


def rollout_global_motion(root_6d, velocity, init_trans=None):
    """root_6d (B, F + 1, 6), velocity (B, F, 3) in the previous root frame -> (root rotations of frames
    1..F (B, F, 3, 3), translations (B, F, 3) = cumulative sum of R_root[t-1] v[t] (+ init_trans))."""
    R = rotation_6d_to_matrix_rows(root_6d)
    world_velocity = (R[:, :-1] @ velocity[..., None])[..., 0]
    trans = torch.cumsum(world_velocity, dim=1)
    if init_trans is not None:
        trans = trans + init_trans
    return R[:, 1:], trans


def camera_angular_velocity(cam_from_world_R, fps: float):
    """WHAM's camera input: 6D(R[t-1] R[t]^T) - 6D(I), times fps, from world-to-camera rotations (F, 3, 3);
    frame 0 repeats frame 1. Returns (F, 6)."""
    R = torch.as_tensor(cam_from_world_R)
    if R.dim() != 3 or R.shape[1:] != (3, 3) or R.shape[0] < 2:
        raise ValueError(f"cam_from_world_R must have shape (F >= 2, 3, 3), got {tuple(R.shape)}")
    relative = matrix_to_rotation_6d_rows(R[:-1] @ R[1:].transpose(-1, -2))
    velocity = (relative - torch.tensor(IDENTITY_6D, dtype=R.dtype)) * fps
    return torch.cat([velocity[:1], velocity], dim=0)


def keypoint_inputs(keypoints, confidence, box, image_size):
    """WHAM's per-frame input from pixel keypoints.

    keypoints (F, 17, 2) pixels; confidence (F, 17); box (F, 3) = (centre x, centre y, side) of the square
    person box in pixels; image_size (width, height). Returns (x (F, 37), mask (F, 17)):
    x = [2 (k - centre) / side  (34) | 2 centre / max(W, H) - (W, H) / max(W, H)  (2) | side / max(W, H)].
    """
    keypoints = torch.as_tensor(keypoints, dtype=torch.float64)
    box = torch.as_tensor(box, dtype=keypoints.dtype)
    f = keypoints.shape[0]
    if keypoints.shape != (f, NUM_KEYPOINTS, 2) or box.shape != (f, 3):
        raise ValueError(f"keypoints must be (F, 17, 2) and box (F, 3), got {tuple(keypoints.shape)} and "
                         f"{tuple(box.shape)}")
    width, height = (float(v) for v in image_size)
    longest = max(width, height)
    centre, side = box[:, None, :2], box[:, None, 2:]
    local = 2 * (keypoints - centre) / side
    location = torch.cat([2 * box[:, :2] / longest - torch.tensor([width, height], dtype=box.dtype) / longest,
                          box[:, 2:] / longest], dim=-1)
    mask = torch.as_tensor(confidence) < MASK_CONFIDENCE
    return torch.cat([local.reshape(f, -1), location], dim=-1), mask


def load_wham(path: str | os.PathLike | None = None, dtype: torch.dtype = torch.float32) -> WhamLifter:
    """WHAM's modules from the official checkpoint ('model' -> state dict; the SMPL buffers it also holds are
    ignored, as WHAM's loader does). path None -> $M3C_MODELS/wham/wham_vit_w_3dpw.pth.tar. Eval mode."""
    file = ckpt.resolve_path(path, WHAM_SOURCE)
    raw = ckpt.read_checkpoint(file, WHAM_SOURCE)
    state = ckpt.strip_prefix(ckpt.take_state_dict(raw, ("model", ""), file, WHAM_SOURCE), "module.")
    feature_dim = IMAGE_FEATURE_DIM
    if "integrator.layer1.weight" in state:  # the ResNet variant reads 2048-d features
        feature_dim = int(state["integrator.layer1.weight"].shape[1]) - CONTEXT_DIM
    model = WhamLifter(feature_dim).to(dtype)
    ckpt.load_into(model, state, file, WHAM_SOURCE, ignore_prefixes=("smpl.",))
    return model.eval()


__all__ = ["WhamLifter", "MotionEncoder", "TrajectoryDecoder", "compose_root", "Integrator", "MotionDecoder",
           "TrajectoryRefiner", "rollout_global_motion", "camera_angular_velocity", "keypoint_inputs", "load_wham"]
