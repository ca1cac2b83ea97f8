"""SMPL linear blend skinning in torch, batched, in the smplx style (einsum blend shapes, batched rigid
transforms, dense skinning). Used by torch-side models and as the benchmark's reference; differentiable."""

from __future__ import annotations

import torch

from m3c.body.model_file import BodyModelData


def axis_angle_to_matrix(axis_angle: torch.Tensor) -> torch.Tensor:
    """... x 3 -> ... x 3 x 3 (Rodrigues, with a small-angle series for stable gradients at zero)."""
    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True)
    small = theta2 < 1e-8
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2_safe)
    x, y, z = axis_angle.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*axis_angle.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device).expand_as(K)
    return eye + a[..., None] * K + b[..., None] * (K @ K)


class TorchBodyModel(torch.nn.Module):
    """Holds the model arrays as buffers. forward(pose N x J x 3, betas N x B, transl N x 3)."""

    def __init__(self, data: BodyModelData, dtype: torch.dtype = torch.float32):
        super().__init__()
        V, J = data.num_vertices, data.num_joints
        self.register_buffer("v_template", torch.as_tensor(data.v_template, dtype=dtype))
        self.register_buffer("shapedirs", torch.as_tensor(data.shapedirs, dtype=dtype))
        self.register_buffer("posedirs", torch.as_tensor(data.posedirs.reshape(3 * V, -1).T.copy(), dtype=dtype))
        self.register_buffer("J_regressor", torch.as_tensor(data.J_regressor, dtype=dtype))
        self.register_buffer("weights", torch.as_tensor(data.weights, dtype=dtype))
        self.parents = [int(p) for p in data.parents]
        self.num_joints = J

    def forward(self, pose: torch.Tensor, betas: torch.Tensor, transl: torch.Tensor | None = None):
        n = pose.shape[0]
        J = self.num_joints
        v_shaped = self.v_template + torch.einsum("bl,mkl->bmk", betas, self.shapedirs)
        rest = torch.einsum("bik,ji->bjk", v_shaped, self.J_regressor)
        rot = axis_angle_to_matrix(pose.reshape(n, J, 3))
        eye = torch.eye(3, dtype=pose.dtype, device=pose.device)
        feature = (rot[:, 1:] - eye).reshape(n, -1)
        v_posed = v_shaped + (feature @ self.posedirs).reshape(n, -1, 3)
        rel = rest.clone()
        rel[:, 1:] = rest[:, 1:] - rest[:, self.parents[1:]]
        local = torch.cat([torch.cat([rot, rel[..., None]], dim=-1),
                           torch.tensor([0, 0, 0, 1], dtype=pose.dtype).expand(n, J, 1, 4)], dim=-2)
        chain = [local[:, 0]]
        for j in range(1, J):
            chain.append(chain[self.parents[j]] @ local[:, j])
        world = torch.stack(chain, dim=1)
        posed_joints = world[:, :, :3, 3]
        rest_h = torch.cat([rest, torch.zeros_like(rest[..., :1])], dim=-1)
        A = world - torch.nn.functional.pad((world @ rest_h[..., None]), (3, 0))
        T = torch.einsum("vj,bjxy->bvxy", self.weights, A)
        v_h = torch.cat([v_posed, torch.ones_like(v_posed[..., :1])], dim=-1)
        verts = (T @ v_h[..., None])[..., :3, 0]
        if transl is not None:
            verts = verts + transl[:, None]
            posed_joints = posed_joints + transl[:, None]
        return verts, posed_joints
