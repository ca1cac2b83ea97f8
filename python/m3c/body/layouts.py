"""Reduction of SMPL-H (52 joints) and SMPL-X (55 joints) bodies to SMPL's 24-joint layout.

Fingers are merged into one hand joint per side (weights summed, joint at the mean of the four knuckles),
SMPL-X jaw and eyes into the head; pose blend shapes of the removed joints are dropped and the new hand
joints get none. This is exact for poses with flat hands and a closed jaw, the poses M3C estimates.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from m3c.body.joint_names import SMPL_PARENTS
from m3c.body.model_file import BodyModelData, BodyModelFileError

# First joint of each side's 15 finger joints (index, middle, pinky, ring, thumb; 3 each) and extra head joints.
_LAYOUTS = {52: {"left": 22, "right": 37, "head_extra": ()}, 55: {"left": 25, "right": 40, "head_extra": (22, 23, 24)}}
_HEAD = 15


def to_smpl_layout(data: BodyModelData) -> BodyModelData:
    J = data.num_joints
    if J == 24:
        return data
    if J not in _LAYOUTS:
        raise BodyModelFileError(f"{data.name}: {J} joints is neither SMPL (24), SMPL-H (52) nor SMPL-X (55)")
    layout = _LAYOUTS[J]
    V = data.num_vertices
    weights = np.zeros((V, 24))
    weights[:, :22] = data.weights[:, :22]
    regressor = np.zeros((24, V))
    regressor[:22] = data.J_regressor[:22]
    for new_joint, side in ((22, "left"), (23, "right")):
        first = layout[side]
        weights[:, new_joint] = data.weights[:, first:first + 15].sum(axis=1)
        knuckles = [first, first + 3, first + 6, first + 9]
        regressor[new_joint] = data.J_regressor[knuckles].mean(axis=0)
    for extra in layout["head_extra"]:
        weights[:, _HEAD] += data.weights[:, extra]
    posedirs = np.zeros((V, 3, 207))
    posedirs[:, :, :189] = data.posedirs[:, :, :189]
    return replace(data, weights=weights, J_regressor=regressor, posedirs=posedirs,
                   parents=np.asarray(SMPL_PARENTS, dtype=np.int64), name=f"{data.name} (SMPL layout)")
