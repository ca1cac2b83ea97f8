"""HuMoR's 339-d motion state, built from SMPL parameters, and its canonical frame.

The state of frame t (HuMoR config 'smpl+joints+contacts', input rotations as matrices), in this order:

    trans 3 | trans_vel 3 | root_orient 9 (row-major) | root_orient_vel 3 | pose_body 21 x 9 |
    joints 22 x 3 | joints_vel 22 x 3                                                       = 339

expressed in a ground frame: z up, the floor at z = 0 (HuMoR was trained on AMASS in that frame, 30 fps).
Velocities are central differences (x[t+1] - x[t-1]) / 2h, so a sequence of T frames gives T - 2 states
(frames 1 .. T-2). The angular velocity w is read off the skew matrix (dR/dt) R^T, averaging its
antisymmetric pairs.

HuMoR scores a transition x_prev -> x_next in the canonical frame of x_prev: a rotation about +z that takes
the body's right direction (minus the first column of the root rotation) to +x, the translation's xy moved to
the origin (height kept), and joints rotated about the vertical through the pelvis, so the pelvis keeps its
offset from the SMPL translation. Velocities are only rotated.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from m3c.models.rotations import axis_angle_to_matrix, matrix_to_axis_angle

STATE_DIM = 339
LATENT_DIM = 48
NUM_BODY_JOINTS = 21  # SMPL joints 1..21 (no hands)
NUM_STATE_JOINTS = 22  # SMPL joints 0..21
HUMOR_FPS = 30.0

TRANS = slice(0, 3)
TRANS_VEL = slice(3, 6)
ROOT_ORIENT = slice(6, 15)
ROOT_ORIENT_VEL = slice(15, 18)
POSE_BODY = slice(18, 207)
JOINTS = slice(207, 273)
JOINTS_VEL = slice(273, 339)

# The decoder predicts changes: rotations as axis-angle (applied on the left), everything else additive,
# then 9 contact logits.
DECODER_OUTPUT_DIM = 216
OUT_TRANS = slice(0, 3)
OUT_TRANS_VEL = slice(3, 6)
OUT_ROOT_ORIENT = slice(6, 9)
OUT_ROOT_ORIENT_VEL = slice(9, 12)
OUT_POSE_BODY = slice(12, 75)
OUT_JOINTS = slice(75, 141)
OUT_JOINTS_VEL = slice(141, 207)
OUT_CONTACTS = slice(207, 216)

# HuMoR's contact OUTPUTS (its decoder's per-joint contact logits), not M3C's contact joints (m3c.body.joint_names).
HUMOR_CONTACT_JOINT_NAMES = ("hips", "leftLeg", "rightLeg", "leftFoot", "rightFoot", "leftToeBase",
                             "rightToeBase", "leftHand", "rightHand")
HUMOR_CONTACT_JOINTS = (0, 4, 5, 7, 8, 10, 11, 20, 21)  # SMPL joint indices of the contact outputs


def _as_tensor(x, like: torch.Tensor | None = None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x
    dtype = like.dtype if like is not None else torch.float64
    return torch.as_tensor(x, dtype=dtype)


def _rotmats(x: torch.Tensor, count: int, name: str) -> torch.Tensor:
    """(T, count, 3) axis-angle, (T, 3*count), or (T, count, 3, 3) matrices -> (T, count, 3, 3)."""
    if x.dim() >= 3 and x.shape[-2:] == (3, 3):
        return x.reshape(x.shape[0], count, 3, 3)
    if x.shape[-1] == 3 * count or (x.dim() >= 2 and x.shape[-2:] == (count, 3)):
        return axis_angle_to_matrix(x.reshape(x.shape[0], count, 3))
    raise ValueError(f"{name} must have shape (T, {count}, 3) / (T, {3 * count}) axis-angle or "
                     f"(T, {count}, 3, 3) matrices, got {tuple(x.shape)}")


# ----------------------------------------------------------------------------------------------------------
# The ground frame


def ground_from_plane(normal, offset) -> tuple[torch.Tensor, torch.Tensor]:
    """Rigid transform into HuMoR's ground frame from a plane {x : n.x + offset = 0} in world coordinates.

    normal: (..., 3) pointing to the side the person stands on (need not be unit); offset: (...) in metres.
    Returns (R (..., 3, 3), t (..., 3)) with p_ground = R p_world + t: R n = +z (the smallest such rotation)
    and the plane maps to z = 0, so z is the signed height above the floor.
    """
    n = _as_tensor(normal)
    offset = _as_tensor(offset, n)
    norm = n.norm(dim=-1, keepdim=True)
    if bool((norm <= 0).any()):
        raise ValueError("ground plane normal must be non-zero")
    n = n / norm
    d = offset / norm[..., 0]
    ez = torch.zeros_like(n)
    ez[..., 2] = 1
    v = torch.cross(n, ez, dim=-1)  # rotation axis * sin(angle)
    c = n[..., 2]
    zero = torch.zeros_like(c)
    K = torch.stack([zero, -v[..., 2], v[..., 1], v[..., 2], zero, -v[..., 0], -v[..., 1], v[..., 0], zero],
                    -1).reshape(*c.shape, 3, 3)
    eye = torch.eye(3, dtype=n.dtype).expand_as(K)
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=n.dtype)).expand_as(K)
    near_down = (c < -1 + 1e-9)[..., None, None]
    scale = (1 / (1 + c).clamp_min(1e-9))[..., None, None]
    R = torch.where(near_down, flip, eye + K + (K @ K) * scale)
    t = torch.zeros_like(n)
    t[..., 2] = d
    return R, t


def transform_smpl(R: torch.Tensor, t: torch.Tensor, trans: torch.Tensor, root_orient: torch.Tensor,
                   joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Moves a posed SMPL body by p -> R p + t (R (..., 3, 3), t (..., 3)).

    SMPL rotates the body about its rest pelvis j0 = joints[0] - trans, so the new translation is
    R (trans + j0) + t - j0. root_orient: (..., 3, 3); joints: (..., J, 3).
    """
    j0 = joints[..., 0, :] - trans
    new_trans = (R @ (trans + j0)[..., None])[..., 0] + t - j0
    new_root = R @ root_orient
    new_joints = joints @ R.transpose(-1, -2) + t[..., None, :]
    return new_trans, new_root, new_joints


# ----------------------------------------------------------------------------------------------------------
# States from SMPL parameters


def angular_velocity(R_prev: torch.Tensor, R_cur: torch.Tensor, R_next: torch.Tensor, h: float) -> torch.Tensor:
    """w with [w]x ~ (dR/dt) R^T from a central difference of rotation matrices (..., 3, 3) -> (..., 3)."""
    W = ((R_next - R_prev) / (2 * h)) @ R_cur.transpose(-1, -2)
    return torch.stack([(W[..., 2, 1] - W[..., 1, 2]) / 2, (W[..., 0, 2] - W[..., 2, 0]) / 2,
                        (W[..., 1, 0] - W[..., 0, 1]) / 2], -1)


def build_states(trans, root_orient, pose_body, joints, fps: float = HUMOR_FPS,
                 ground_from_world: tuple | None = None) -> torch.Tensor:
    """HuMoR states of frames 1 .. T-2 of a sequence of T >= 3 frames.

    trans: (T, 3) SMPL translation, metres; root_orient: (T, 3) axis-angle or (T, 3, 3);
    pose_body: (T, 21, 3) / (T, 63) axis-angle or (T, 21, 3, 3), SMPL joints 1..21;
    joints: (T, >=22, 3) posed SMPL joints (only 0..21 are used), same frame and units as trans;
    fps: frame rate of the sequence (HuMoR was trained at 30);
    ground_from_world: None if the inputs are already in the ground frame (z up, floor z = 0), else (R, t)
        from ground_from_plane, one for all frames (3, 3)/(3,) or one per frame (T, 3, 3)/(T, 3); state t
        uses frame t's transform for frames t-1, t, t+1.
    Returns (T - 2, 339), differentiable in every input.
    """
    trans = _as_tensor(trans)
    T = trans.shape[0]
    if trans.shape != (T, 3) or T < 3:
        raise ValueError(f"trans must have shape (T >= 3, 3), got {tuple(trans.shape)}")
    root = _rotmats(_as_tensor(root_orient, trans), 1, "root_orient")[:, 0]
    pose = _rotmats(_as_tensor(pose_body, trans), NUM_BODY_JOINTS, "pose_body")
    joints = _as_tensor(joints, trans)
    if joints.dim() != 3 or joints.shape[0] != T or joints.shape[1] < NUM_STATE_JOINTS or joints.shape[2] != 3:
        raise ValueError(f"joints must have shape (T={T}, >=22, 3), got {tuple(joints.shape)}")
    joints = joints[:, :NUM_STATE_JOINTS]
    if root.shape[0] != T or pose.shape[0] != T:
        raise ValueError("trans, root_orient, pose_body and joints must have the same number of frames")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    h = 1.0 / fps

    def frames(k: int):  # the sequence shifted by k in {-1, 0, 1}, aligned with states 1..T-2
        s = slice(1 + k, T - 1 + k)
        tr, ro, jo = trans[s], root[s], joints[s]
        if ground_from_world is not None:
            R, t = (_as_tensor(v, trans) for v in ground_from_world)
            if R.dim() == 3:
                if R.shape[0] != T:
                    raise ValueError(f"per-frame ground_from_world needs T={T} transforms, got {R.shape[0]}")
                R, t = R[1:T - 1], t[1:T - 1]
            tr, ro, jo = transform_smpl(R, t, tr, ro, jo)
        return tr, ro, jo

    (tr_p, ro_p, jo_p), (tr_c, ro_c, jo_c), (tr_n, ro_n, jo_n) = frames(-1), frames(0), frames(1)
    n = T - 2
    return torch.cat([
        tr_c,
        (tr_n - tr_p) / (2 * h),
        ro_c.reshape(n, 9),
        angular_velocity(ro_p, ro_c, ro_n, h),
        pose[1:T - 1].reshape(n, 9 * NUM_BODY_JOINTS),
        jo_c.reshape(n, 3 * NUM_STATE_JOINTS),
        ((jo_n - jo_p) / (2 * h)).reshape(n, 3 * NUM_STATE_JOINTS),
    ], dim=-1)


def build_states_from_body(body_model, trans, root_orient, pose_body, betas, fps: float = HUMOR_FPS,
                           ground_from_world: tuple | None = None) -> torch.Tensor:
    """build_states with the joints posed by a torch body model (m3c.body.torch_lbs.TorchBodyModel, SMPL
    layout, 24 joints); hand joints 22, 23 are left at rest. betas: (B,) or (T, B)."""
    trans = _as_tensor(trans)
    T = trans.shape[0]
    root_aa = _as_tensor(root_orient, trans).reshape(T, 1, 3)
    body_aa = _as_tensor(pose_body, trans).reshape(T, NUM_BODY_JOINTS, 3)
    extra = torch.zeros(T, body_model.num_joints - 1 - NUM_BODY_JOINTS, 3, dtype=trans.dtype)
    pose = torch.cat([root_aa, body_aa, extra], dim=1)
    betas = _as_tensor(betas, trans)
    if betas.dim() == 1:
        betas = betas.expand(T, -1)
    _, joints = body_model(pose, betas, trans)
    return build_states(trans, root_aa, body_aa, joints, fps, ground_from_world)


# ----------------------------------------------------------------------------------------------------------
# Canonical frame


@dataclass(frozen=True)
class CanonicalFrame:
    """world -> canonical: p' = A (p + shift - pelvis) + pelvis for joints, A (p + shift) for the translation,
    A v for velocities and rotations. Leading dims follow the states it was computed from."""

    rotation: torch.Tensor  # A (..., 3, 3), a rotation about +z
    shift: torch.Tensor  # (..., 3) = (-trans_x, -trans_y, 0)
    pelvis: torch.Tensor  # (..., 3) = (pelvis_xy - trans_xy, 0): the pelvis offset from the SMPL translation


def canonical_frame(x: torch.Tensor) -> CanonicalFrame:
    """The canonical frame of states x (..., 339)."""
    R = x[..., ROOT_ORIENT].reshape(*x.shape[:-1], 3, 3)
    right_x, right_y = -R[..., 0, 0], -R[..., 1, 0]
    norm = torch.sqrt(right_x * right_x + right_y * right_y).clamp_min(1e-12)
    c, s = right_x / norm, right_y / norm
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    A = torch.stack([c, s, zero, -s, c, zero, zero, zero, one], -1).reshape(*c.shape, 3, 3)
    trans = x[..., TRANS]
    shift = torch.stack([-trans[..., 0], -trans[..., 1], zero], -1)
    pelvis = torch.stack([x[..., JOINTS.start] - trans[..., 0], x[..., JOINTS.start + 1] - trans[..., 1], zero], -1)
    return CanonicalFrame(A, shift, pelvis)


def _rotate(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """A (..., 3, 3) applied to v (..., K*3) -> (..., K*3)."""
    pts = v.reshape(*v.shape[:-1], -1, 3)
    return (pts @ A.transpose(-1, -2)).reshape(v.shape)


def to_canonical(x: torch.Tensor, frame: CanonicalFrame) -> torch.Tensor:
    """States (..., 339) in world (ground) coordinates -> the canonical frame."""
    A = frame.rotation
    joints = x[..., JOINTS].reshape(*x.shape[:-1], NUM_STATE_JOINTS, 3)
    offset = (frame.shift - frame.pelvis)[..., None, :]
    joints = (joints + offset) @ A.transpose(-1, -2) + frame.pelvis[..., None, :]
    root = A @ x[..., ROOT_ORIENT].reshape(*x.shape[:-1], 3, 3)
    return torch.cat([
        _rotate(A, x[..., TRANS] + frame.shift),
        _rotate(A, x[..., TRANS_VEL]),
        root.reshape(*x.shape[:-1], 9),
        _rotate(A, x[..., ROOT_ORIENT_VEL]),
        x[..., POSE_BODY],
        joints.reshape(*x.shape[:-1], 3 * NUM_STATE_JOINTS),
        _rotate(A, x[..., JOINTS_VEL]),
    ], dim=-1)


def from_canonical(x: torch.Tensor, frame: CanonicalFrame) -> torch.Tensor:
    """Inverse of to_canonical."""
    At = frame.rotation.transpose(-1, -2)
    joints = x[..., JOINTS].reshape(*x.shape[:-1], NUM_STATE_JOINTS, 3)
    joints = (joints - frame.pelvis[..., None, :]) @ frame.rotation - (frame.shift - frame.pelvis)[..., None, :]
    root = At @ x[..., ROOT_ORIENT].reshape(*x.shape[:-1], 3, 3)
    return torch.cat([
        _rotate(At, x[..., TRANS]) - frame.shift,
        _rotate(At, x[..., TRANS_VEL]),
        root.reshape(*x.shape[:-1], 9),
        _rotate(At, x[..., ROOT_ORIENT_VEL]),
        x[..., POSE_BODY],
        joints.reshape(*x.shape[:-1], 3 * NUM_STATE_JOINTS),
        _rotate(At, x[..., JOINTS_VEL]),
    ], dim=-1)


def canonicalize_pair(x_prev: torch.Tensor, x_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Both states (..., 339) expressed in the canonical frame of x_prev, as HuMoR's networks expect."""
    frame = canonical_frame(x_prev)
    return to_canonical(x_prev, frame), to_canonical(x_next, frame)


# ----------------------------------------------------------------------------------------------------------
# Decoder output -> state, state -> SMPL


def apply_decoder_output(x_prev: torch.Tensor, out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The next state from the previous one (..., 339) and the decoder's raw output (..., 216), both in the
    canonical frame of x_prev: rotations R = Rodrigues(out) R_prev, the rest x_prev + out.
    Returns (x_next (..., 339), contact logits (..., 9))."""
    lead = x_prev.shape[:-1]
    root = axis_angle_to_matrix(out[..., OUT_ROOT_ORIENT]) @ x_prev[..., ROOT_ORIENT].reshape(*lead, 3, 3)
    pose = axis_angle_to_matrix(out[..., OUT_POSE_BODY].reshape(*lead, NUM_BODY_JOINTS, 3)) @ \
        x_prev[..., POSE_BODY].reshape(*lead, NUM_BODY_JOINTS, 3, 3)
    x_next = torch.cat([
        x_prev[..., TRANS] + out[..., OUT_TRANS],
        x_prev[..., TRANS_VEL] + out[..., OUT_TRANS_VEL],
        root.reshape(*lead, 9),
        x_prev[..., ROOT_ORIENT_VEL] + out[..., OUT_ROOT_ORIENT_VEL],
        pose.reshape(*lead, 9 * NUM_BODY_JOINTS),
        x_prev[..., JOINTS] + out[..., OUT_JOINTS],
        x_prev[..., JOINTS_VEL] + out[..., OUT_JOINTS_VEL],
    ], dim=-1)
    return x_next, out[..., OUT_CONTACTS]


def state_to_smpl(x: torch.Tensor) -> dict:
    """SMPL parameters in a state (..., 339): trans (..., 3), root_orient (..., 3) and pose_body (..., 21, 3)
    axis-angle, joints (..., 22, 3)."""
    lead = x.shape[:-1]
    return {
        "trans": x[..., TRANS],
        "root_orient": matrix_to_axis_angle(x[..., ROOT_ORIENT].reshape(*lead, 3, 3)),
        "pose_body": matrix_to_axis_angle(x[..., POSE_BODY].reshape(*lead, NUM_BODY_JOINTS, 3, 3)),
        "joints": x[..., JOINTS].reshape(*lead, NUM_STATE_JOINTS, 3),
    }

