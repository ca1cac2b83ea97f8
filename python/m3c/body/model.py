"""The public body model: a thin class over the C++ core (m3c._core) with numpy in, numpy out."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c import _core
from m3c.body.joint_names import (COCO17_SOURCES, H36M_TO_J14, SMPL_KEYPOINT_VERTICES, SMPLX_KEYPOINT_VERTICES)
from m3c.body.layouts import to_smpl_layout
from m3c.body.model_file import BodyModelData, load_model_file


@dataclass
class BodyOutput:
    vertices: np.ndarray  # N x V x 3
    joints: np.ndarray  # N x J x 3


class BodyModel:
    """SMPL-layout body model evaluated by the C++ core.

    pose: N x J x 3 (or N x 3J) axis-angle, root first; betas: B or N x B; transl: None, 3 or N x 3 (metres).
    Computed in float32 when numpy's result type of pose, betas and transl is float32 (or float16), else in
    float64 (a float32 pose with float64 betas gives float64, as numpy would); integer and bool arrays convert
    to float. Other dtypes (longdouble, complex, object), NaN/inf values and results that would overflow raise
    ValueError naming the argument.
    """

    def __init__(self, data: BodyModelData):
        self.data = data
        self._core = _core.BodyModel(data.v_template, data.shapedirs, data.posedirs, data.J_regressor,
                                     data.weights, data.parents, data.faces)

    @classmethod
    def from_file(cls, path: str | Path, num_betas: int | None = 10, smpl_layout: bool = False) -> "BodyModel":
        """Loads .pkl/.npz; smpl_layout reduces SMPL-H/SMPL-X bodies to SMPL's 24 joints."""
        data = load_model_file(path, num_betas=num_betas)
        return cls(to_smpl_layout(data) if smpl_layout else data)

    @property
    def num_vertices(self) -> int:
        return self._core.num_vertices

    @property
    def num_joints(self) -> int:
        return self._core.num_joints

    @property
    def num_betas(self) -> int:
        return self._core.num_betas

    @property
    def faces(self) -> np.ndarray:
        return self.data.faces

    @property
    def parents(self) -> np.ndarray:
        return self.data.parents

    def forward(self, pose, betas, transl=None) -> BodyOutput:
        vertices, joints = _core.forward(self._core, pose, betas, transl)
        return BodyOutput(vertices, joints)

    def joints(self, pose, betas, transl=None) -> np.ndarray:
        """Posed joints N x J x 3 without skinning the mesh."""
        return _core.forward_kinematics(self._core, pose, betas, transl)

    def joints_jacobian(self, pose, betas, transl=None):
        """(joints N x J x 3, jacobian N x 3J x (3 + 3J + B)), columns [transl | pose | betas]."""
        return _core.joints_jacobian(self._core, pose, betas, transl)

    # Keypoints -----------------------------------------------------------------------------------------
    def regressor(self, vertex_weights: np.ndarray | None = None, joint_weights: np.ndarray | None = None):
        """A keypoint regressor: k = vertex_weights @ vertices + joint_weights @ joints (K x V, K x J)."""
        K = (vertex_weights if vertex_weights is not None else joint_weights).shape[0]
        vw = np.zeros((K, self.num_vertices)) if vertex_weights is None else vertex_weights
        jw = np.zeros((K, self.num_joints)) if joint_weights is None else joint_weights
        return _core.KeypointRegressor(self._core, vw, jw)

    def keypoint_vertex_ids(self) -> dict:
        if self.data.keypoint_vertex_ids:
            return dict(self.data.keypoint_vertex_ids)
        if self.num_vertices == 6890:
            return dict(SMPL_KEYPOINT_VERTICES)
        if self.num_vertices == 10475:
            return dict(SMPLX_KEYPOINT_VERTICES)
        raise ValueError(
            f"{self.data.name}: no keypoint vertex table for a {self.num_vertices}-vertex model; "
            "add keypoint_names / keypoint_vertex_ids to the model file"
        )

    def vertex_selection(self, vertex_ids) -> "_core.KeypointRegressor":
        ids = np.asarray(vertex_ids, dtype=int)
        vw = np.zeros((len(ids), self.num_vertices))
        vw[np.arange(len(ids)), ids] = 1.0
        return self.regressor(vertex_weights=vw)

    def coco17_regressor(self) -> "_core.KeypointRegressor":
        """COCO-17 keypoints: face points from vertices, limbs from SMPL joints (24-joint layout)."""
        return self.regressor(*self.coco17_weights())

    def coco17_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """The COCO-17 regressor's (vertex_weights 17 x V, joint_weights 17 x J), for code outside the core."""
        if self.num_joints != 24:
            raise ValueError(f"COCO-17 needs the SMPL 24-joint layout, this model has {self.num_joints} joints; "
                             "load it with smpl_layout=True")
        table = self.keypoint_vertex_ids()
        vw = np.zeros((17, self.num_vertices))
        jw = np.zeros((17, self.num_joints))
        for k, (kind, key) in enumerate(COCO17_SOURCES):
            if kind == "vertex":
                vw[k, table[key]] = 1.0
            else:
                jw[k, key] = 1.0
        return vw, jw

    def h36m_regressor(self, j_regressor_h36m: np.ndarray, evaluation_joints: bool = False):
        """The H36M-17 regressor (17 x V) users bring; evaluation_joints keeps the 14 evaluation joints."""
        reg = np.asarray(j_regressor_h36m, dtype=np.float64)
        if reg.shape != (17, self.num_vertices):
            raise ValueError(f"J_regressor_h36m must have shape (17, {self.num_vertices}), got {reg.shape}")
        return self.regressor(vertex_weights=reg[list(H36M_TO_J14)] if evaluation_joints else reg)

    def keypoints(self, regressor, pose, betas, transl=None) -> np.ndarray:
        return _core.keypoints(self._core, regressor, pose, betas, transl)

    def keypoints_jacobian(self, regressor, pose, betas, transl=None):
        return _core.keypoints_jacobian(self._core, regressor, pose, betas, transl)
