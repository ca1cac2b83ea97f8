"""The hands of M3C's open body model: 15 finger joints per hand in SMPL-H/MANO order, posed relative to the
body's wrists (see data/m3c_open_hands.md).

The hand model is a separate file (data/m3c_open_hands.npz, CC0, built by tools/build_open_hand_model.py from
the same MakeHuman assets as the body), so the 24-joint body is unchanged. Its finger joints hang off the
body's wrist joints (20, 21) as in SMPL-H; the body's hand joints (22, 23), which M3C keeps at rest, move
rigidly with the wrists, and the hand layer re-skins the vertices they carry onto the finger joints.

Layout (SMPL-H, MANO): per hand index1-3, middle1-3, pinky1-3, ring1-3, thumb1-3; joint 1 of each finger hangs
off the wrist, 2 off 1, 3 off 2. Tips are the ends of each finger's third bone, in the same finger order. Rest
pose (zero finger pose): the open model's T-pose hands (palms down, fingers along +-x). Rotations are
axis-angle relative to the parent, in the body's rest axes (as SMPL-H's hand poses).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

HAND_MODEL_FILE = "m3c_open_hands.npz"
HAND_MODEL_NAME = "m3c-open-hm08-hands"
SIDES = ("left", "right")
FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-H / MANO order
HAND_JOINT_NAMES = tuple(f"{finger}{k}" for finger in FINGERS for k in (1, 2, 3))
HAND_PARENTS = tuple(-1 if k == 0 else 3 * f + k - 1 for f in range(5) for k in range(3))  # -1: the wrist
TIP_NAMES = tuple(f"{finger}_tip" for finger in FINGERS)
TIP_JOINTS = (2, 5, 8, 11, 14)  # the joint whose bone ends at each tip
WRIST_JOINTS = {"left": 20, "right": 21}  # SMPL joints the fingers hang off
HAND_JOINTS = {"left": 22, "right": 23}  # SMPL joints the fingers replace
SMPLH_FIRST_FINGER_JOINT = {"left": 22, "right": 37}  # SMPL-H's 52 joints: 22 body, 15 left, 15 right

# MediaPipe's 21 hand landmarks (wrist; thumb CMC, MCP, IP, tip; index MCP, PIP, DIP, tip; middle; ring;
# pinky) as rows of [wrist, 15 finger joints, 5 tips] (hand_keypoints).
MEDIAPIPE_HAND_NAMES = (
    "wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip", "index_mcp", "index_pip", "index_dip",
    "index_tip", "middle_mcp", "middle_pip", "middle_dip", "middle_tip", "ring_mcp", "ring_pip", "ring_dip",
    "ring_tip", "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)
MEDIAPIPE_FROM_HAND = (0, 13, 14, 15, 20, 1, 2, 3, 16, 4, 5, 6, 17, 10, 11, 12, 19, 7, 8, 9, 18)
# Bones between landmarks, for drawing (MediaPipe's hand connections).
MEDIAPIPE_HAND_BONES = ((0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (5, 9), (9, 10),
                        (10, 11), (11, 12), (9, 13), (13, 14), (14, 15), (15, 16), (13, 17), (0, 17),
                        (17, 18), (18, 19), (19, 20))


@dataclass(frozen=True)
class HandModel:
    """Arrays of a hand model; side axis first (left, right), B shape components (the body's betas).

    wrist_template: 2 x 3 and wrist_shapedirs: 2 x 3 x B, the body's rest wrist joints (its J_regressor);
    joints_template: 2 x 15 x 3, joints_shapedirs: 2 x 15 x 3 x B, the rest finger joints;
    tips_template: 2 x 5 x 3, tips_shapedirs: 2 x 5 x 3 x B, the rest fingertips;
    vertex_ids[side]: the body vertices the fingers carry (H); weights[side]: H x 15, their finger weights,
    which sum to the body's weight on its hand joint.
    """

    wrist_template: np.ndarray
    wrist_shapedirs: np.ndarray
    joints_template: np.ndarray
    joints_shapedirs: np.ndarray
    tips_template: np.ndarray
    tips_shapedirs: np.ndarray
    vertex_ids: dict
    weights: dict
    name: str = HAND_MODEL_NAME
    body_model: str = ""

    def rest(self, betas) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(wrists 2 x 3, finger joints 2 x 15 x 3, tips 2 x 5 x 3) of the rest pose of shape betas (B,)."""
        betas = np.asarray(betas, dtype=np.float64)[: self.wrist_shapedirs.shape[-1]]
        B = len(betas)
        return (self.wrist_template + self.wrist_shapedirs[..., :B] @ betas,
                self.joints_template + self.joints_shapedirs[..., :B] @ betas,
                self.tips_template + self.tips_shapedirs[..., :B] @ betas)


def hand_model_path() -> Path:
    return Path(str(resources.files("m3c.body") / "data" / HAND_MODEL_FILE))


def load_hand_model(path: str | Path | None = None) -> HandModel:
    """The hand model file (default: the shipped open model's hands)."""
    path = hand_model_path() if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"hand model {path} is missing; rebuild it with "
                                "python tools/build_open_hand_model.py")
    with np.load(path, allow_pickle=False) as f:
        a = {k: f[k] for k in f.files}
    if tuple(str(n) for n in a["joint_names"]) != HAND_JOINT_NAMES:
        raise ValueError(f"{path}: finger joints {a['joint_names']} are not SMPL-H's {HAND_JOINT_NAMES}")
    return HandModel(
        **{k: a[k].astype(np.float64) for k in ("wrist_template", "wrist_shapedirs", "joints_template",
                                                 "joints_shapedirs", "tips_template", "tips_shapedirs")},
        vertex_ids={s: a[f"{s}_vertex_ids"].astype(np.int64) for s in SIDES},
        weights={s: a[f"{s}_weights"].astype(np.float64) for s in SIDES},
        name=str(a["model_name"]), body_model=str(a["body_model"]))


def hand_model_for(body_name: str) -> HandModel | None:
    """The hand model of a body model named body_name: the open model's hands, or None for other bodies (an
    SMPL-H/SMPL-X file's own fingers are not used yet)."""
    from m3c.body.open_model import OPEN_MODEL_NAME

    return load_hand_model() if body_name == OPEN_MODEL_NAME else None


@dataclass
class HandOutput:
    """Posed hands: joints N x 2 x 15 x 3, tips N x 2 x 5 x 3, transforms N x 2 x 15 x 4 x 4 (each finger
    joint's world rotation and position), wrists N x 2 x 3."""

    joints: np.ndarray
    tips: np.ndarray
    transforms: np.ndarray
    wrists: np.ndarray

    def keypoints(self) -> np.ndarray:
        """N x 2 x 21 x 3 in MediaPipe's landmark order."""
        stacked = np.concatenate([self.wrists[:, :, None], self.joints, self.tips], axis=2)
        return stacked[:, :, list(MEDIAPIPE_FROM_HAND)]


def rotations(axis_angle: np.ndarray) -> np.ndarray:
    """... x 3 axis-angle -> ... x 3 x 3."""
    axis_angle = np.asarray(axis_angle, dtype=np.float64)
    return Rotation.from_rotvec(axis_angle.reshape(-1, 3)).as_matrix().reshape(axis_angle.shape[:-1] + (3, 3))


def pose_hands(hand: HandModel, betas, wrist_rotation: np.ndarray, wrist_position: np.ndarray,
               hand_pose: np.ndarray) -> HandOutput:
    """Forward kinematics of the fingers. betas: B; wrist_rotation: N x 2 x 3 x 3, the wrists' world
    rotations; wrist_position: N x 2 x 3, the posed wrist joints; hand_pose: N x 2 x 15 x 3 axis-angle (zeros:
    rest)."""
    wrist_rest, joints_rest, tips_rest = hand.rest(betas)
    R_local = rotations(hand_pose)
    wrist_rotation = np.asarray(wrist_rotation, dtype=np.float64)
    wrist_position = np.asarray(wrist_position, dtype=np.float64)
    n = len(R_local)
    R_world = np.zeros((n, 2, 15, 3, 3))
    position = np.zeros((n, 2, 15, 3))
    for j, p in enumerate(HAND_PARENTS):
        if p < 0:
            parent_R, parent_x, offset = wrist_rotation, wrist_position, joints_rest[:, j] - wrist_rest
        else:
            parent_R, parent_x = R_world[:, :, p], position[:, :, p]
            offset = joints_rest[:, j] - joints_rest[:, p]
        position[:, :, j] = parent_x + np.einsum("nsab,sb->nsa", parent_R, offset)
        R_world[:, :, j] = parent_R @ R_local[:, :, j]
    tip_offsets = tips_rest - joints_rest[:, list(TIP_JOINTS)]
    tips = position[:, :, list(TIP_JOINTS)] + np.einsum("nsfab,sfb->nsfa", R_world[:, :, list(TIP_JOINTS)],
                                                        tip_offsets)
    transforms = np.zeros((n, 2, 15, 4, 4))
    transforms[..., :3, :3] = R_world
    transforms[..., :3, 3] = position
    transforms[..., 3, 3] = 1.0
    return HandOutput(position, tips, transforms, wrist_position)


def wrist_frames(model, pose: np.ndarray, betas, transl=None) -> tuple[np.ndarray, np.ndarray]:
    """The body's wrists: world rotations N x 2 x 3 x 3 (the local rotations composed along the chain) and
    posed positions N x 2 x 3, of SMPL-layout poses N x 24 x 3 (root first)."""
    pose = np.asarray(pose, dtype=np.float64)
    R = rotations(pose)
    parents = np.asarray(model.parents)
    world = [None] * len(parents)
    for j, p in enumerate(parents):
        world[j] = R[:, j] if p < 0 else world[p] @ R[:, j]
    joints = model.joints(pose, betas, transl)
    rotation = np.stack([world[WRIST_JOINTS[s]] for s in SIDES], axis=1)
    position = np.stack([joints[:, WRIST_JOINTS[s]] for s in SIDES], axis=1)
    return rotation, position


def skin_hands(hand: HandModel, betas, rest_vertices: np.ndarray, body_vertices: np.ndarray,
               wrist_rotation: np.ndarray, wrist_position: np.ndarray, hand_pose: np.ndarray) -> np.ndarray:
    """The body's posed vertices N x V x 3 with the fingers posed: each hand vertex moves by its finger
    weights w_f from the wrist's rigid transform A_w (which the body's unrotated hand joint applies) to the
    finger joints' A_f: v' = v + sum_f w_f (A_f - A_w) v_rest. rest_vertices: V x 3, the body's rest vertices
    of shape betas (no pose blend shapes: the open model has none)."""
    out = np.array(body_vertices, dtype=np.float64, copy=True)
    posed = pose_hands(hand, betas, wrist_rotation, wrist_position, hand_pose)
    wrist_rest, joints_rest, _ = hand.rest(betas)
    for s, side in enumerate(SIDES):
        ids, w = hand.vertex_ids[side], hand.weights[side]
        v = rest_vertices[ids]  # H x 3
        wrist_moved = (np.einsum("nab,hb->nha", wrist_rotation[:, s], v - wrist_rest[s])
                       + wrist_position[:, s, None])
        finger_moved = (np.einsum("nfab,fhb->nfha", posed.transforms[:, s, :, :3, :3],
                                  v[None] - joints_rest[s][:, None]) + posed.joints[:, s, :, None])
        out[:, ids] += np.einsum("hf,nfha->nha", w, finger_moved) - w.sum(axis=1)[None, :, None] * wrist_moved
    return out
