"""Retargeting onto published skeletons (`m3c export --rig`): one retarget for every rig, the rigs as data.

Where each skeleton's bone names and hierarchy come from (read through public copies, cited by
repository/page):
- Mixamo: the 25 body bones of an auto-rigged Mixamo character, `mixamorig:` prefix (Hips > Spine > Spine1 >
  Spine2 > Neck > Head > HeadTop_End, Spine2 > LeftShoulder > LeftArm > LeftForeArm > LeftHand, Hips >
  LeftUpLeg > LeftLeg > LeftFoot > LeftToeBase > LeftToe_End), as listed in home-gamejam/stick-game
  docs/rigs.md; Mixamo characters are rigged in the T pose.
- UE5 mannequin (Manny/Quinn): Epic's own template in the IK Rig auto-characterizer (Engine/Plugins/Animation/
  IKRig/.../IKRigAutoCharacterizer.cpp, "UE5 Mannequin": root > pelvis > spine_01..spine_05 > neck_01 >
  neck_02 > head, spine_05 > clavicle_l > upperarm_l > lowerarm_l > hand_l, pelvis > thigh_l > calf_l > foot_l
  > ball_l, mirrored _r); the UE5 mannequin's reference pose is the A pose (arms about 45 degrees down).
- Unity: the Humanoid avatar's body slots, HumanBodyBones (docs.unity3d.com ScriptReference/HumanBodyBones):
  Hips, Spine, Chest, UpperChest, Neck, Head, Left/RightShoulder, UpperArm, LowerArm, Hand, UpperLeg,
  LowerLeg, Foot, Toes; Unity's avatar configuration expects the T pose.
- Blender Rigify, "Basic Human" metarig's deform (DEF-) bones, as listed in home-gamejam/stick-game
  docs/rigs.md: DEF-spine (the hips) .001 .. .006 (.004 the neck, .006 the head), DEF-pelvis.L,
  DEF-thigh.L(.001), DEF-shin.L(.001), DEF-foot.L, DEF-toe.L, DEF-shoulder.L, DEF-upper_arm.L(.001),
  DEF-forearm.L(.001), DEF-hand.L (mirrored .R). A generated Rigify rig parents its DEF bones to ORG/MCH
  bones, so a DEF-only hierarchy is a convention: here the metarig's parents (thighs and pelvis.L under
  DEF-spine, shoulders under DEF-spine.003); game-export add-ons such as NyankoNyan/Rigify-Move-DEF put the
  thighs under DEF-pelvis.L instead. The breast bones are left out (nothing of the body model drives them).
  Rest pose used: the T pose.
- smpl: the body model's own 24 joints and rest pose (today's BVH/GLB/FBX skeleton).

Finger bones (when the results hold hand poses; the rig is body-only otherwise), hanging off each rig's hand
bone, mapped onto the hand model's SMPL-H finger joints (m3c.body.hands: joint 1 near the knuckle, 3 the
last phalanx) and fingertips:
- Mixamo: mixamorig:LeftHandThumb1..4, LeftHandIndex1..4, LeftHandMiddle1..4, LeftHandRing1..4,
  LeftHandPinky1..4 (Right likewise), 1 nearest the palm and 4 the tip's end bone, each chained to the
  previous, 1 under LeftHand (DayalGupta03/Sign_Bridge1 boneNames.md; the same names in
  vircadia/vircadia-native-core's mannequin .fst joint list).
- UE5 mannequin: thumb_01_l..thumb_03_l under hand_l; index/middle/ring/pinky_metacarpal_l under hand_l, with
  <finger>_01_l..03_l below each (_r likewise), as the UE5 mannequin's bone lists in public tool scripts
  have them (a Maya "UE5 standard bone list" export set, root .. pinky_03_r; Mixamo -> UE5 retarget tables
  mapping LeftHandIndex1 to index_metacarpal_l); no tip bones. The metacarpals sit META_FRACTION of the
  way from the wrist to the knuckle (M3C's choice: the hand model has no metacarpal joints) and follow the
  hand.
- Unity: HumanBodyBones' finger slots (docs.unity3d.com ScriptReference/HumanBodyBones: LeftThumbProximal,
  Intermediate, Distal; LeftIndex.., LeftMiddle.., LeftRing.., LeftLittle.. "1st / 2nd / 3rd phalange"),
  each chain under LeftHand.
- Rigify: DEF-palm.01.L..04.L (index, middle, ring, pinky) under DEF-hand.L, DEF-f_index.01.L..03.L under
  DEF-palm.01.L (f_middle under palm.02, f_ring .03, f_pinky .04), DEF-thumb.01.L..03.L under DEF-palm.01.L,
  the human metarig's parents (the Rigify bone-group lists in public add-ons name the same DEF- bones;
  makehuman's makewalk humanik.trg maps HumanIK's LeftHandThumb1 to thumb.01.L, LeftHandIndex1 to
  f_index.01.L). Palm bones placed as UE5's metacarpals.
- smpl: SMPL-H's finger joints left_index1 .. right_thumb3 under left_wrist / right_wrist (as the BVH and
  GLB exports name them).
In the rest pose the fingers keep the rest hand's shape (the open model's straight, palm-down T-pose hand),
turned with the wrist. A hand bone's axis points at its middle finger's first bone. Frames where the results
hold no hand (NaN hand poses) get the rest hand (zero finger rotations), as in the BVH and GLB exports.

Retarget. Every bone's head sits on a joint of the retarget's skeleton (`joint`: SMPL's 24, then with the
hands 30 finger joints and 10 fingertips, finger_joint) or on a fixed point of a segment (`between`: twist,
extra spine, end, metacarpal and palm bones; they carry no rotation of their own and follow their parent).
Bone lengths are therefore the performer's own (the body model's joints at the fitted betas). The target's
rest pose is the body model's rest with world rotations W_j per joint (limbs straightened: arms along +-x in
the T pose, 45 degrees below it in the A pose, legs vertical; torso and head as the body model's rest), moved
so that the mesh stands on y = 0 with the pelvis above the origin. A frame's body-model world rotations G_j
then give each bone the world frame F_b = G_d W_d^T B_b (d the joint driving the bone, B_b the bone's rest
frame), so forward kinematics puts every mapped bone exactly on the source's world joint. Bone axes: B_b has
its primary axis along the bone (head to the first child; +Y for Mixamo, Unity and Rigify as in Blender, +X
for UE5 as in Unreal), the roll chosen by M3C (second axis from the character's forward or up), not copied
from the vendors' files. Axes of the file: the results' world (y up, metres, +z the first camera's viewing
direction).

Options (what `m3c export --rig` passes):
- root_motion "performer": the true metric world path; "in-place": the pelvis's horizontal path removed (x = z
  = 0), its height and every rotation (the heading) kept.
- smoothing "off" / "standard" / "strong": a Savitzky-Golay filter (polynomial order 2) over windows of
  SMOOTHING_SECONDS on each joint's local rotation as a quaternion (signs made continuous first, renormalised
  after) and on the root translation; the planted feet are re-locked after it.
- foot_lock: on frames where a foot is planted (results.npz `contacts` > CONTACT_THRESHOLD at its ankle or
  toe) the ankle is put back where the source has it (after the in-place shift) by a two-bone IK on hip and
  knee (the knee stays in the plane of its current bend; where the smoothed hips are too far for the leg, the
  whole body is lowered just enough first), and the foot and toe get the source's world
  rotations. The retarget and the smoothing then add no sliding; sliding the source itself has is not removed.
- reference_pose "tpose" / "apose": an extra first frame in that pose (facing +z, above the first frame's
  pelvis); the motion starts one frame later.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

ROOT_MOTIONS = ("performer", "in-place")
REFERENCE_POSES = ("none", "tpose", "apose")
SMOOTHING_SECONDS = {"off": 0.0, "standard": 0.25, "strong": 0.5}
CONTACT_THRESHOLD = 0.5           # results.npz contacts are probabilities
CONTACT_JOINTS = (7, 8, 10, 11)   # results.npz contacts' columns: left/right ankle, left/right foot (SMPL)
A_POSE_DEGREES = 45.0             # arms below horizontal in the A pose
REACH_MARGIN = 1e-6               # metres: foot locking straightens a leg to its length less this
_SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
_LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))   # hip, knee, ankle, foot per side (left, right)
# The retarget's skeleton with hands: SMPL's 24 joints, then 30 finger joints (m3c.body.hands: left hand's
# 15 in SMPL-H order, then the right's), then 10 fingertips (left, right; SMPL-H finger order), which never
# rotate.
SMPLH_FINGERS = ("index", "middle", "pinky", "ring", "thumb")   # m3c.body.hands.FINGERS
FINGER_JOINTS, TIP_JOINTS_START, NUM_HAND_SKELETON = 24, 54, 64
META_FRACTION = 0.25   # a metacarpal / palm bone's head: this far from the wrist toward its finger's knuckle


def finger_joint(side: int, finger: str, k: int) -> int:
    """The retarget skeleton's joint of `finger` (SMPL-H name) on side 0 (left) / 1 (right): k 1..3 its
    joints, 4 its tip."""
    f = SMPLH_FINGERS.index(finger)
    return TIP_JOINTS_START + 5 * side + f if k == 4 else FINGER_JOINTS + 15 * side + 3 * f + k - 1


def _hand_parents() -> tuple[int, ...]:
    parents = list(_SMPL_PARENTS)
    for side in (0, 1):
        for finger in SMPLH_FINGERS:
            parents += [20 + side, finger_joint(side, finger, 1), finger_joint(side, finger, 2)]
    for side in (0, 1):
        parents += [finger_joint(side, finger, 3) for finger in SMPLH_FINGERS]
    return tuple(parents)


_PARENTS = _hand_parents()   # (64,) the first 24 are SMPL's


@dataclass(frozen=True)
class Bone:
    name: str
    parent: str | None
    joint: int                                      # the body-model joint the head sits on; -1: the floor
    between: tuple[int, float] | None = None     # head at joint + t (other - joint); follows its parent


@dataclass(frozen=True)
class Rig:
    name: str
    bones: tuple[Bone, ...]
    rest_pose: str          # "tpose", "apose" or "model" (the body model's own rest)
    bone_axis: str          # "y", "x" (the axis along the bone) or "none" (identity rest frames)

    @property
    def names(self) -> list[str]:
        return [b.name for b in self.bones]

    @property
    def parents(self) -> np.ndarray:
        index = {b.name: i for i, b in enumerate(self.bones)}
        return np.array([index[b.parent] if b.parent is not None else -1 for b in self.bones])

    def mapped(self) -> dict[str, int]:
        """bone name -> joint of the retarget's skeleton (0..23 SMPL's, 24..53 the fingers', 54..63 the
        fingertips; finger_joint), for the bones that sit on (and are driven by) a joint."""
        return {b.name: b.joint for b in self.bones if b.joint >= 0 and b.between is None}

    @property
    def finger_bones(self) -> list[str]:
        return [b.name for b in self.bones if _is_finger(b)]

    def body_only(self) -> Rig:
        """The rig without its finger bones (for results that hold no hand poses)."""
        bones = tuple(b for b in self.bones if not _is_finger(b))
        return Rig(self.name, bones, self.rest_pose, self.bone_axis)


def _is_finger(bone: Bone) -> bool:
    return bone.joint >= FINGER_JOINTS or (bone.between is not None and bone.between[0] >= FINGER_JOINTS)


_CENTRAL = (0, 3, 6, 9, 12, 15)   # SMPL joints on the midline; the others come in pairs, left then right


def _sides(template: list[tuple], left: str, right: str) -> list[Bone]:
    """Bones from (name, parent, left joint, between), `{s}` in names; right joints are left + 1 (SMPL)."""
    bones = []
    for side, offset in ((left, 0), (right, 1)):
        def shift(j: int, offset: int = offset) -> int:
            return j if j in _CENTRAL else j + offset
        for name, parent, joint, between in template:
            bones.append(Bone(name.format(s=side), parent.format(s=side) if parent else None, shift(joint),
                              (shift(between[0]), between[1]) if between else None))
    return bones


_RIG_FINGERS = ("thumb", "index", "middle", "ring", "pinky")   # the order the rigs list them in


def _chains(hand: str, side: int, name, metacarpal=None, tips: bool = False,
            thumb_parent: str | None = None) -> list[Bone]:
    """One hand's finger bones: name(finger, k) for k = 1..3 (4: the tip bone, when tips) on finger joints k;
    metacarpal(finger) (None: none) a bone from the wrist toward that finger's knuckle (META_FRACTION of the
    way), which the finger's first bone hangs off (not the thumb's); thumb_parent: the thumb's parent bone
    (default the hand)."""
    bones = []
    order = _RIG_FINGERS if thumb_parent is None else _RIG_FINGERS[1:] + _RIG_FINGERS[:1]   # parents first
    for finger in order:
        parent = hand
        meta = metacarpal(finger) if metacarpal is not None else None
        if meta is not None:
            bones.append(Bone(meta, hand, 20 + side, (finger_joint(side, finger, 1), META_FRACTION)))
            parent = meta
        if finger == "thumb" and thumb_parent is not None:
            parent = thumb_parent
        for k in range(1, 5 if tips else 4):
            bones.append(Bone(name(finger, k), parent, finger_joint(side, finger, k)))
            parent = name(finger, k)
    return bones


def _mixamo() -> Rig:
    p = "mixamorig:"
    core = [Bone(p + "Hips", None, 0), Bone(p + "Spine", p + "Hips", 3), Bone(p + "Spine1", p + "Spine", 6),
            Bone(p + "Spine2", p + "Spine1", 9), Bone(p + "Neck", p + "Spine2", 12),
            Bone(p + "Head", p + "Neck", 15),
            Bone(p + "HeadTop_End", p + "Head", 12, (15, 2.5))]
    limbs = [(p + "{s}Shoulder", p + "Spine2", 13, None), (p + "{s}Arm", p + "{s}Shoulder", 16, None),
             (p + "{s}ForeArm", p + "{s}Arm", 18, None), (p + "{s}Hand", p + "{s}ForeArm", 20, None),
             (p + "{s}UpLeg", p + "Hips", 1, None), (p + "{s}Leg", p + "{s}UpLeg", 4, None),
             (p + "{s}Foot", p + "{s}Leg", 7, None), (p + "{s}ToeBase", p + "{s}Foot", 10, None),
             (p + "{s}Toe_End", p + "{s}ToeBase", 7, (10, 1.6))]
    hands = []
    for side, label in enumerate(("Left", "Right")):
        hands += _chains(f"{p}{label}Hand", side, lambda f, k, label=label: f"{p}{label}Hand{f.title()}{k}",
                         tips=True)
    return Rig("mixamo", tuple(core + _sides(limbs, "Left", "Right") + hands), "tpose", "y")


def _ue5() -> Rig:
    core = [Bone("root", None, -1), Bone("pelvis", "root", 0), Bone("spine_01", "pelvis", 3),
            Bone("spine_02", "spine_01", 3, (6, 0.5)), Bone("spine_03", "spine_02", 6),
            Bone("spine_04", "spine_03", 6, (9, 0.5)), Bone("spine_05", "spine_04", 9),
            Bone("neck_01", "spine_05", 12), Bone("neck_02", "neck_01", 12, (15, 0.5)),
            Bone("head", "neck_02", 15)]
    limbs = [("clavicle_{s}", "spine_05", 13, None), ("upperarm_{s}", "clavicle_{s}", 16, None),
             ("lowerarm_{s}", "upperarm_{s}", 18, None), ("hand_{s}", "lowerarm_{s}", 20, None),
             ("thigh_{s}", "pelvis", 1, None), ("calf_{s}", "thigh_{s}", 4, None),
             ("foot_{s}", "calf_{s}", 7, None),
             ("ball_{s}", "foot_{s}", 10, None)]
    hands = []
    for side, s in enumerate(("l", "r")):
        hands += _chains(f"hand_{s}", side, lambda f, k, s=s: f"{f}_0{k}_{s}",
                         lambda f, s=s: None if f == "thumb" else f"{f}_metacarpal_{s}")
    return Rig("ue5", tuple(core + _sides(limbs, "l", "r") + hands), "apose", "x")


def _unity() -> Rig:
    core = [Bone("Hips", None, 0), Bone("Spine", "Hips", 3), Bone("Chest", "Spine", 6),
            Bone("UpperChest", "Chest", 9), Bone("Neck", "UpperChest", 12), Bone("Head", "Neck", 15)]
    limbs = [("{s}Shoulder", "UpperChest", 13, None), ("{s}UpperArm", "{s}Shoulder", 16, None),
             ("{s}LowerArm", "{s}UpperArm", 18, None), ("{s}Hand", "{s}LowerArm", 20, None),
             ("{s}UpperLeg", "Hips", 1, None), ("{s}LowerLeg", "{s}UpperLeg", 4, None),
             ("{s}Foot", "{s}LowerLeg", 7, None), ("{s}Toes", "{s}Foot", 10, None)]
    phalanges = ("Proximal", "Intermediate", "Distal")
    hands = []
    for side, label in enumerate(("Left", "Right")):
        hands += _chains(f"{label}Hand", side, lambda f, k, label=label: (
            f"{label}{'Little' if f == 'pinky' else f.title()}{phalanges[k - 1]}"))
    return Rig("unity", tuple(core + _sides(limbs, "Left", "Right") + hands), "tpose", "y")


def _rigify() -> Rig:
    core = [Bone("DEF-spine", None, 0), Bone("DEF-spine.001", "DEF-spine", 3),
            Bone("DEF-spine.002", "DEF-spine.001", 6), Bone("DEF-spine.003", "DEF-spine.002", 9),
            Bone("DEF-spine.004", "DEF-spine.003", 12), Bone("DEF-spine.005", "DEF-spine.004", 12, (15, 0.5)),
            Bone("DEF-spine.006", "DEF-spine.005", 15)]
    limbs = [("DEF-pelvis.{s}", "DEF-spine", 0, (1, 0.0)),
             ("DEF-thigh.{s}", "DEF-spine", 1, None), ("DEF-thigh.{s}.001", "DEF-thigh.{s}", 1, (4, 0.5)),
             ("DEF-shin.{s}", "DEF-thigh.{s}.001", 4, None),
             ("DEF-shin.{s}.001", "DEF-shin.{s}", 4, (7, 0.5)),
             ("DEF-foot.{s}", "DEF-shin.{s}.001", 7, None), ("DEF-toe.{s}", "DEF-foot.{s}", 10, None),
             ("DEF-shoulder.{s}", "DEF-spine.003", 13, None),
             ("DEF-upper_arm.{s}", "DEF-shoulder.{s}", 16, None),
             ("DEF-upper_arm.{s}.001", "DEF-upper_arm.{s}", 16, (18, 0.5)),
             ("DEF-forearm.{s}", "DEF-upper_arm.{s}.001", 18, None),
             ("DEF-forearm.{s}.001", "DEF-forearm.{s}", 18, (20, 0.5)),
             ("DEF-hand.{s}", "DEF-forearm.{s}.001", 20, None)]
    palms = {"index": "01", "middle": "02", "ring": "03", "pinky": "04"}
    hands = []
    for side, s in enumerate(("L", "R")):
        hands += _chains(f"DEF-hand.{s}", side, lambda f, k, s=s: (
            f"DEF-thumb.0{k}.{s}" if f == "thumb" else f"DEF-f_{f}.0{k}.{s}"),
            lambda f, s=s: f"DEF-palm.{palms[f]}.{s}" if f in palms else None,
            thumb_parent=f"DEF-palm.01.{s}")
    return Rig("rigify", tuple(core + _sides(limbs, "L", "R") + hands), "tpose", "y")


def _smpl() -> Rig:
    from m3c.body.joint_names import SMPL_JOINT_NAMES

    names = SMPL_JOINT_NAMES
    bones = [Bone(names[j], names[p] if p >= 0 else None, j) for j, p in enumerate(_SMPL_PARENTS)]
    for side, label in enumerate(("left", "right")):   # SMPL-H's names, as the BVH and GLB exports have them
        bones += _chains(f"{label}_wrist", side, lambda f, k, label=label: f"{label}_{f}{k}")
    return Rig("smpl", tuple(bones), "model", "none")


RIGS = {"smpl": _smpl, "mixamo": _mixamo, "ue5": _ue5, "unity": _unity, "rigify": _rigify}


def get_rig(name: str) -> Rig:
    if name not in RIGS:
        raise ValueError(f"unknown rig {name!r}; choose one of {', '.join(RIGS)}")
    rig = RIGS[name]()
    if np.any(rig.parents >= np.arange(len(rig.bones))):
        raise ValueError(f"rig {name}: a bone comes before its parent")
    return rig


# --- rotations ---------------------------------------------------------------------------------------------

def align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the smallest rotation taking direction a onto direction b (both (..., 3))."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = np.sum(a * b, axis=-1)
    angle = np.arctan2(s, c)
    safe = np.where(s[..., None] > 1e-12, axis / np.maximum(s[..., None], 1e-300), 0.0)
    rotvec = (safe * angle[..., None]).reshape(-1, 3)
    out = Rotation.from_rotvec(rotvec).as_matrix().reshape(*a.shape[:-1], 3, 3)
    flip = (s < 1e-12) & (c < 0)   # opposite directions: half a turn about any axis normal to a
    if np.any(flip):
        normal = np.cross(a[flip], [1.0, 0.0, 0.0])
        normal[np.linalg.norm(normal, axis=-1) < 1e-6] = np.cross(a[flip], [0.0, 1.0, 0.0])[
            np.linalg.norm(normal, axis=-1) < 1e-6]
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        out[flip] = Rotation.from_rotvec(np.pi * normal).as_matrix()
    return out


def pose_world_rotations(rest_joints: np.ndarray, pose: str) -> np.ndarray:
    """(J, 3, 3) world rotations W_j turning the body model's rest (J = 24 joints, or 64 with the hands)
    into `pose` (tpose, apose, model). The fingers keep the rest hand's shape: they turn with their wrist."""
    W = np.tile(np.eye(3), (len(rest_joints), 1, 1))
    if pose == "model":
        return W
    if pose not in ("tpose", "apose"):
        raise ValueError(f"unknown rest pose {pose!r}")
    J = rest_joints
    drop = np.radians(A_POSE_DEGREES) if pose == "apose" else 0.0
    for side, sign in ((0, 1.0), (1, -1.0)):           # SMPL's left is +x
        arm = np.array([sign * np.cos(drop), -np.sin(drop), 0.0])
        for j, child in ((16 + side, 18 + side), (18 + side, 20 + side), (20 + side, 22 + side)):
            W[j] = align(J[child] - J[j], arm)
        W[22 + side] = W[20 + side]
        hip, knee, ankle, _ = _LEGS[side]
        W[hip] = align(J[knee] - J[hip], np.array([0.0, -1.0, 0.0]))
        W[knee] = align(J[ankle] - J[knee], np.array([0.0, -1.0, 0.0]))
    for j in range(24, len(W)):
        W[j] = W[_PARENTS[j]]
    return W


def forward_kinematics(local: np.ndarray, rest_joints: np.ndarray, root: np.ndarray) -> tuple[np.ndarray,
                                                                                            np.ndarray]:
    """Body model: (n, J, 3, 3) local rotations, (J, 3) rest joints, (n, 3) root positions ->
    (world rotations (n, J, 3, 3), world joints (n, J, 3)); J = 24 (SMPL) or 64 (with the hands)."""
    G = np.empty_like(local)
    x = np.empty(local.shape[:2] + (3,))
    G[:, 0], x[:, 0] = local[:, 0], root
    for j in range(1, local.shape[1]):
        p = _PARENTS[j]
        G[:, j] = G[:, p] @ local[:, j]
        x[:, j] = x[:, p] + G[:, p] @ (rest_joints[j] - rest_joints[p])
    return G, x


def local_from_world(G: np.ndarray) -> np.ndarray:
    local = G.copy()
    for j in range(1, G.shape[1]):
        local[:, j] = np.swapaxes(G[:, _PARENTS[j]], -1, -2) @ G[:, j]
    return local


def smooth_motion(local: np.ndarray, root: np.ndarray, fps: float,
                  level: str) -> tuple[np.ndarray, np.ndarray]:
    """Savitzky-Golay (order 2, SMOOTHING_SECONDS[level] windows) on quaternions of (n, J, 3, 3) local
    rotations (hemisphere-continuous, renormalised) and on the (n, 3) root path. Short tracks get the longest
    odd window they allow (none under 5 frames)."""
    if level not in SMOOTHING_SECONDS:
        raise ValueError(f"unknown smoothing {level!r}; choose one of {', '.join(SMOOTHING_SECONDS)}")
    n = len(local)
    window = round(SMOOTHING_SECONDS[level] * fps) | 1
    window = min(window, n if n % 2 else n - 1)
    if level == "off" or window < 5:
        return local, root
    from scipy.signal import savgol_filter  # seconds to import: only when smoothing

    quat = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
    for i in range(1, n):
        quat[i][np.sum(quat[i] * quat[i - 1], axis=-1) < 0] *= -1
    quat = savgol_filter(quat, window, 2, axis=0, mode="interp")
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    smoothed = Rotation.from_quat(quat.reshape(-1, 4)).as_matrix().reshape(local.shape)
    return smoothed, savgol_filter(root, window, 2, axis=0, mode="interp")


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, target: np.ndarray, upper: float,
                lower: float) -> np.ndarray:
    """(m, 3) knee positions that put the ankle on `target` with segment lengths upper (hip-knee) and lower
    (knee-ankle), the knee in the plane of hip, target and its current position (as close to reach as the
    lengths allow)."""
    to_target = target - hip
    d = np.linalg.norm(to_target, axis=-1)
    u = to_target / np.maximum(d[:, None], 1e-9)
    d = np.clip(d, abs(upper - lower) + REACH_MARGIN, upper + lower - REACH_MARGIN)
    bend = knee - hip
    v = bend - np.sum(bend * u, axis=-1, keepdims=True) * u
    v_norm = np.linalg.norm(v, axis=-1, keepdims=True)
    fallback = np.cross(u, [1.0, 0.0, 0.0])           # a straight leg: bend forward-ish
    v = np.where(v_norm > 1e-6, v / np.maximum(v_norm, 1e-12), fallback)
    cos_a = np.clip((upper ** 2 + d ** 2 - lower ** 2) / (2 * upper * d), -1.0, 1.0)
    return hip + upper * (cos_a[:, None] * u + np.sqrt(1 - cos_a ** 2)[:, None] * v)


def reach_drop(x: np.ndarray, rest_joints: np.ndarray, planted: np.ndarray,
               target_x: np.ndarray) -> np.ndarray:
    """(n,) how far (metres) to lower the body so that every planted ankle's target is within its leg's reach
    (0 where it already is): the smallest s >= 0 with |target - (hip - s y)| <= leg length - REACH_MARGIN."""
    drop = np.zeros(len(x))
    J = rest_joints
    for side, (hip, knee, ankle, _) in enumerate(_LEGS):
        reach = np.linalg.norm(J[knee] - J[hip]) + np.linalg.norm(J[ankle] - J[knee]) - REACH_MARGIN
        d = target_x[:, ankle] - x[:, hip]
        far = planted[:, side] & (np.linalg.norm(d, axis=-1) > reach)
        disc = d[far, 1] ** 2 + reach ** 2 - np.sum(d[far] ** 2, axis=-1)
        drop[far] = np.maximum(drop[far], -d[far, 1] - np.sqrt(np.maximum(disc, 0.0)))
    return drop


def lock_feet(G: np.ndarray, x: np.ndarray, rest_joints: np.ndarray, planted: np.ndarray,
              target_G: np.ndarray, target_x: np.ndarray) -> np.ndarray:
    """World rotations (n, 24, 3, 3) with, on planted frames (n, 2 bool: left, right), the ankle moved onto
    target_x's by two-bone IK on hip and knee, and the ankle and foot given target_G's world rotations."""
    G = G.copy()
    J = rest_joints
    for side, (hip, knee, ankle, foot) in enumerate(_LEGS):
        rows = np.flatnonzero(planted[:, side])
        if not len(rows):
            continue
        upper, lower = np.linalg.norm(J[knee] - J[hip]), np.linalg.norm(J[ankle] - J[knee])
        new_knee = two_bone_ik(x[rows, hip], x[rows, knee], target_x[rows, ankle], upper, lower)
        thigh = np.einsum("mij,j->mi", G[rows, hip], J[knee] - J[hip])
        R1 = align(thigh, new_knee - x[rows, hip])
        G[rows, hip] = R1 @ G[rows, hip]
        shin = np.einsum("mij,j->mi", R1 @ G[rows, knee], J[ankle] - J[knee])
        G[rows, knee] = align(shin, target_x[rows, ankle] - new_knee) @ R1 @ G[rows, knee]
        G[rows, ankle] = target_G[rows, ankle]
        G[rows, foot] = target_G[rows, foot]
    return G


# --- the retarget ------------------------------------------------------------------------------------------

@dataclass
class RigMotion:
    """One track on a rig. World frame of the results (y up, metres). B bones, n frames."""
    rig: Rig
    names: list[str]
    parents: np.ndarray             # (B,) -1 for the top bone
    rest_positions: np.ndarray      # (B, 3) bone heads in the rest pose (world, standing on y = 0)
    rest_frames: np.ndarray         # (B, 3, 3) bones' rest orientations in the world (columns: bone axes)
    rest_translations: np.ndarray   # (B, 3) each bone's head in its parent's rest frame
    rest_rotations: np.ndarray      # (B, 3, 3) each bone's rest orientation relative to its parent
    rotations: np.ndarray           # (n, B, 3, 3) each bone's orientation relative to its parent, per frame
    translation_bone: int           # the bone whose translation is animated (the pelvis)
    translations: np.ndarray        # (n, 3) that bone's head in its parent's frame, per frame
    world_positions: np.ndarray     # (n, B, 3) bone heads per frame (forward kinematics of the above)
    frames: np.ndarray              # (n,) results' processed frame per key (-1: the reference pose)
    planted: np.ndarray             # (n, 2) feet locked per frame (left, right)
    rest_vertices: np.ndarray       # (V, 3) the performer's mesh in the rig's rest pose
    weights: np.ndarray             # (V, B) skinning weights on the rig's bones


def _bone_frame(direction: np.ndarray, axis: str) -> np.ndarray:
    if axis == "none":
        return np.eye(3)
    d = direction / np.linalg.norm(direction)
    forward, up = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    ref = forward if abs(d @ forward) < 0.7 else up
    if axis == "x":
        ref = up if abs(d @ up) < 0.7 else forward
    second = ref - (ref @ d) * d
    second /= np.linalg.norm(second)
    if axis == "y":      # columns x, y (along), z (second)
        return np.stack([np.cross(d, second), d, second], axis=1)
    return np.stack([d, np.cross(second, d), second], axis=1)   # x (along), y, z (second)


def _rest(rig: Rig, rest_joints: np.ndarray, W: np.ndarray, rest_mesh: np.ndarray, skin: np.ndarray):
    """Rest heads (B, 3), drivers (B,), rest frames (B, 3, 3), rest vertices (V, 3) and weights (V, B)."""
    J = rest_joints
    parents = rig.parents
    drivers = np.empty(len(rig.bones), int)
    model_points = np.empty((len(rig.bones), 3))
    for b, bone in enumerate(rig.bones):
        if bone.joint < 0:
            drivers[b], model_points[b] = -1, J[0]
        elif bone.between is None:
            drivers[b], model_points[b] = bone.joint, J[bone.joint]
            if parents[b] >= 0 and drivers[parents[b]] != _PARENTS[bone.joint]:
                raise ValueError(f"rig {rig.name}: {bone.name}'s parent is not driven by its joint's parent")
        else:
            other, t = bone.between
            drivers[b] = drivers[parents[b]]
            model_points[b] = J[bone.joint] + t * (J[other] - J[bone.joint])
    # The rest mesh: linear blend skinning of the body model's rest mesh by [W_j | P_j - W_j J_j].
    P_joint = np.empty((len(J), 3))
    P_joint[0] = J[0]
    for j in range(1, len(J)):
        p = _PARENTS[j]
        P_joint[j] = P_joint[p] + W[p] @ (J[j] - J[p])
    skin = np.concatenate([skin, np.zeros((len(skin), len(J) - skin.shape[1]))], axis=1)   # tips: none
    per_joint = np.einsum("jab,vjb->vja", W, rest_mesh[:, None, :] - J[None]) + P_joint[None]
    vertices = np.einsum("vj,vja->va", skin, per_joint)
    heads = np.empty_like(model_points)
    for b in range(len(rig.bones)):
        p = parents[b]
        if drivers[b] == -1:
            heads[b] = P_joint[0]
        elif p < 0 or drivers[p] == -1:
            heads[b] = P_joint[drivers[b]]
        else:
            heads[b] = heads[p] + W[drivers[p]] @ (model_points[b] - model_points[p])
    shift = np.array([P_joint[0, 0], vertices[:, 1].min(), P_joint[0, 2]])
    heads, vertices = heads - shift, vertices - shift
    heads[drivers == -1] = [0.0, 0.0, 0.0]   # a floor root (UE5's root) at the origin
    # Bone frames: primary axis to the first child's head (a hand's: to its middle finger's bone), a leaf
    # continuing its parent's direction.
    middle = {finger_joint(side, "middle", 1) for side in (0, 1)}
    frames = np.empty((len(rig.bones), 3, 3))
    for b in range(len(rig.bones)):
        children = list(np.flatnonzero(parents == b))
        if drivers[b] == -1:
            frames[b] = np.eye(3)
            continue
        aim = [c for c in children if rig.bones[c].joint in middle
               or (rig.bones[c].between is not None and rig.bones[c].between[0] in middle)]
        if len(children):
            direction = heads[(aim or children)[0]] - heads[b]
        else:
            direction = heads[b] - heads[parents[b]]
        bone = rig.bones[b]
        if np.linalg.norm(direction) < 1e-6 and bone.between is not None:   # Rigify's pelvis.L: to the hip
            direction = W[drivers[b]] @ (J[bone.between[0]] - J[bone.joint])
        frames[b] = _bone_frame(direction, rig.bone_axis)
    # Skinning weights: each body-model joint's weights on the bone it drives (the hands' on the wrists).
    owner = {}
    for b, bone in enumerate(rig.bones):
        if bone.joint >= 0 and bone.between is None:
            owner[bone.joint] = b
    weights = np.zeros((len(rest_mesh), len(rig.bones)))
    for j in range(skin.shape[1]):
        k = j
        while k not in owner:
            k = _PARENTS[k]
        weights[:, owner[k]] += skin[:, j]
    return heads, drivers, frames, vertices, weights


def retarget(rig: Rig | str, rest_joints: np.ndarray, pose: np.ndarray, root_positions: np.ndarray,
             fps: float, rest_mesh: np.ndarray, skin: np.ndarray, contacts: np.ndarray | None = None,
             root_motion: str = "performer", smoothing: str = "off", foot_lock: bool = True,
             reference_pose: str = "none", frames: np.ndarray | None = None, fingers=None) -> RigMotion:
    """The motion of one track on `rig`.

    rest_joints (24, 3): the body model's rest joints at the track's betas; pose (n, 24, 3) axis-angle (world
    root orientation, then the body's local rotations); root_positions (n, 3): the root joint in the world;
    rest_mesh (V, 3) the body model's rest vertices at the betas, skin (V, 24) its weights; contacts (n, 4)
    results.npz's contact probabilities (None: no foot locking).

    fingers: the track's finger skeleton (m3c.export.source.FingerSkeleton: rest (30, 3) finger joints, tips
    (10, 3), pose (n, 30, 3) local axis-angle, zeros on frames without a hand); skin is then (V, 54), the
    hand vertices weighted on the finger joints (m3c.export.source.finger_skin). None: the rig without its
    finger bones."""
    rig = get_rig(rig) if isinstance(rig, str) else rig
    if fingers is None:
        rig = rig.body_only()
    elif skin.shape[1] != TIP_JOINTS_START:
        raise ValueError(f"with fingers the skinning weights need {TIP_JOINTS_START} columns (24 body, 30 "
                         f"finger joints), got {skin.shape[1]}")
    if root_motion not in ROOT_MOTIONS:
        raise ValueError(f"unknown root motion {root_motion!r}; choose one of {', '.join(ROOT_MOTIONS)}")
    if reference_pose not in REFERENCE_POSES:
        raise ValueError(f"unknown reference pose {reference_pose!r}; choose one of "
                         f"{', '.join(REFERENCE_POSES)}")
    n = len(pose)
    frames = np.arange(n) if frames is None else np.asarray(frames)
    J = np.asarray(rest_joints, dtype=np.float64)
    if fingers is not None:
        J = np.concatenate([J, np.asarray(fingers.rest, np.float64), np.asarray(fingers.tips, np.float64)])
        if len(fingers.pose) != n:
            raise ValueError(f"{len(fingers.pose)} frames of finger poses for {n} frames of body poses")
        pose = np.concatenate([pose, fingers.pose, np.zeros((n, 10, 3))], axis=1)
    local = Rotation.from_rotvec(pose.reshape(-1, 3)).as_matrix().reshape(n, len(J), 3, 3)
    root = np.array(root_positions, dtype=np.float64)
    if root_motion == "in-place":
        root[:, [0, 2]] = 0.0
    source_G, source_x = forward_kinematics(local, J, root)
    local, root = smooth_motion(local, root, fps, smoothing)
    G, x = forward_kinematics(local, J, root)
    planted = np.zeros((n, 2), bool)
    if foot_lock and contacts is not None:
        c = np.asarray(contacts, dtype=np.float64)
        planted = np.stack([np.maximum(c[:, 0], c[:, 2]), np.maximum(c[:, 1], c[:, 3])], 1)
        planted = planted > CONTACT_THRESHOLD
        root[:, 1] -= reach_drop(x, J, planted, source_x)   # a leg too short for its planted foot: hips lower
        G, x = forward_kinematics(local, J, root)
        G = lock_feet(G, x, J, planted, source_G, source_x)
        G, x = forward_kinematics(local_from_world(G), J, root)

    W = pose_world_rotations(J, rig.rest_pose)
    heads, drivers, B, rest_vertices, weights = _rest(rig, J, W, rest_mesh, skin)
    if reference_pose != "none":
        W_ref = pose_world_rotations(J, reference_pose)
        ref_root = np.array([root[0, 0], heads[list(drivers).index(0)][1], root[0, 2]])
        G_ref, x_ref = forward_kinematics(local_from_world(W_ref[None]), J, ref_root[None])
        G, x = np.concatenate([G_ref, G]), np.concatenate([x_ref, x])
        frames = np.concatenate([[-1], frames])
        planted = np.concatenate([np.zeros((1, 2), bool), planted])
    m = len(G)
    parents = rig.parents
    nb = len(rig.bones)
    F = np.empty((m, nb, 3, 3))
    world = np.empty((m, nb, 3))
    for b in range(nb):
        d, p = drivers[b], parents[b]
        if d == -1:
            F[:, b], world[:, b] = B[b], heads[b]
            continue
        F[:, b] = G[:, d] @ W[d].T @ B[b]
        if rig.bones[b].between is None:
            world[:, b] = x[:, d]
        else:
            world[:, b] = world[:, p] + np.einsum("nij,j->ni", G[:, drivers[p]] @ W[drivers[p]].T,
                                                  heads[b] - heads[p])
    rest_t = np.empty((nb, 3))
    rest_r = np.empty((nb, 3, 3))
    rotations = np.empty((m, nb, 3, 3))
    for b in range(nb):
        p = parents[b]
        if p < 0:
            rest_t[b], rest_r[b], rotations[:, b] = heads[b], B[b], F[:, b]
        else:
            rest_t[b] = B[p].T @ (heads[b] - heads[p])
            rest_r[b] = B[p].T @ B[b]
            rotations[:, b] = np.swapaxes(F[:, p], -1, -2) @ F[:, b]
    top = list(drivers).index(0)
    pt = parents[top]
    translations = (world[:, top] if pt < 0
                    else np.einsum("nji,nj->ni", F[:, pt], world[:, top] - world[:, pt]))
    return RigMotion(rig, rig.names, parents, heads, B, rest_t, rest_r, rotations, top, translations, world,
                     frames, planted, rest_vertices, weights)
