"""Rotation conversions shared by the torch models (batched over leading dims, differentiable).

Matrices act on column vectors; a (..., 9) row-major vector is R.reshape(..., 9).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from m3c.body.torch_lbs import axis_angle_to_matrix

__all__ = ["axis_angle_to_matrix", "matrix_to_axis_angle", "rotation_6d_to_matrix_columns",
           "rotation_6d_to_matrix_rows", "matrix_to_rotation_6d_rows"]


def matrix_to_axis_angle(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle, through the quaternion (stable at 0 and pi)."""
    m = R
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Four candidate quaternions (w, x, y, z), each well conditioned where its leading component is large.
    candidates = torch.stack([
        torch.stack([1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                     m[..., 1, 0] - m[..., 0, 1]], -1),
        torch.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                     m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        torch.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                     1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], m[..., 1, 2] + m[..., 2, 1]], -1),
        torch.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
                     1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1),
    ], dim=-2)
    lead = torch.stack([1 + trace, 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                        1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                        1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1)
    best = lead.argmax(-1)
    quat = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4))[..., 0, :]
    quat = F.normalize(quat, dim=-1)
    quat = torch.where(quat[..., :1] < 0, -quat, quat)  # w >= 0: angle in [0, pi]
    w, v = quat[..., 0], quat[..., 1:]
    sin_half = v.norm(dim=-1)
    angle = 2 * torch.atan2(sin_half, w)
    # angle / sin(angle/2) -> 2 as the angle -> 0.
    small = sin_half < 1e-7
    scale = torch.where(small, 2 / w.clamp_min(1e-12), angle / sin_half.clamp_min(1e-30))
    return v * scale[..., None]


def rotation_6d_to_matrix_columns(x: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3), VPoser's convention: x viewed as a 3x2 matrix (row-major), its two columns
    Gram-Schmidt orthonormalised into the first two columns of R; third column = b1 x b2."""
    m = x.reshape(*x.shape[:-1], 3, 2)
    b1 = F.normalize(m[..., 0], dim=-1)
    b2 = F.normalize(m[..., 1] - (b1 * m[..., 1]).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def rotation_6d_to_matrix_rows(x: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3), WHAM's (pytorch3d's) convention: x[:3] and x[3:] orthonormalised into the first
    two ROWS of R; third row = b1 x b2."""
    b1 = F.normalize(x[..., :3], dim=-1)
    a2 = x[..., 3:]
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-2)


def matrix_to_rotation_6d_rows(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two rows, inverse of rotation_6d_to_matrix_rows on rotations."""
    return R[..., :2, :].reshape(*R.shape[:-2], 6)
