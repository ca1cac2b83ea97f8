"""Fast retargeting of BVH motion capture onto the body model's 24 SMPL-layout joints: the source skeleton's
own joint rotations carried over, an inverse-kinematics fit only on the frames where that leaves an error.

m3c.eval.retarget fits every frame by inverse kinematics (30-70 s a clip); a training corpus of thousands of
clips needs something faster. Each SMPL joint j is driven by one BVH joint d(j) placed alike (the thigh by the
upper leg, the knee by the lower leg, ...): its world rotation is the BVH joint's world rotation times a
constant rotation A_j, G_j(t) = R_d(j)(t) A_j, which carries the rest-pose offsets of the source skeleton (its
bones' directions in each joint's own frame) over to the SMPL rest pose. A_j is calibrated per clip from
inverse-kinematics fits of a few frames spread over the clip (the chordal mean of R_d(j)^T G_j over those
frames), so it holds whatever local-frame conventions the file uses. The SMPL joints no BVH joint drives keep
the rotation of their parent (spine2: halfway between the BVH joints that drive spine1 and spine3).

Betas are fitted to the skeleton's bone lengths (Gauss-Newton least squares on the body model's shape space,
the rest joints being linear in the betas); the root translation follows the matched joints in closed form;
the per-joint offsets between where the two skeletons place a joint are the mean residuals in the carrying
bone's frame (as m3c.eval.retarget calibrates them). Frames whose matched joints still miss by more than
refine_threshold_mm get m3c.eval.retarget's per-frame fit, started from and pulled towards the carried-over
pose. The output is m3c.eval.retarget's RetargetedMotion: world frame y up (m3c.ground.world_frame), ground
y = 0, metres, `fps` frames per second.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.eval.retarget import (_UP, JOINT_MAPS, JOINT_WEIGHTS, RetargetConfig, RetargetedMotion, _Fitter,
                               detect_joint_map, global_rotations)
from m3c.io.bvh import BVHMotion, read_bvh

# SMPL joint -> the BVH joint whose rotation drives it, per naming convention (JOINT_MAPS' keys). A pair: the
# rotation halfway between the two. SMPL joints missing here keep their parent's rotation (a local identity).
DRIVER_MAPS = {
    "bandai_namco": {
        "pelvis": "Hips", "spine1": "Spine", "spine2": ("Spine", "Chest"), "spine3": "Chest", "neck": "Neck",
        "head": "Head", "left_collar": "Shoulder_L", "right_collar": "Shoulder_R",
        "left_shoulder": "UpperArm_L", "right_shoulder": "UpperArm_R", "left_elbow": "LowerArm_L",
        "right_elbow": "LowerArm_R", "left_wrist": "Hand_L", "right_wrist": "Hand_R",
        "left_hip": "UpperLeg_L", "right_hip": "UpperLeg_R", "left_knee": "LowerLeg_L",
        "right_knee": "LowerLeg_R", "left_ankle": "Foot_L", "right_ankle": "Foot_R", "left_foot": "Toes_L",
        "right_foot": "Toes_R",
    },
    "cmu_3dsmax": {
        "pelvis": "Hips", "spine1": "lowerback", "spine2": "Chest", "spine3": "Chest2", "neck": "lowerneck",
        "head": "Head", "left_collar": "LeftCollar", "right_collar": "RightCollar",
        "left_shoulder": "LeftShoulder", "right_shoulder": "RightShoulder", "left_elbow": "LeftElbow",
        "right_elbow": "RightElbow", "left_wrist": "LeftWrist", "right_wrist": "RightWrist",
        "left_hip": "LeftHip", "right_hip": "RightHip", "left_knee": "LeftKnee", "right_knee": "RightKnee",
        "left_ankle": "LeftAnkle", "right_ankle": "RightAnkle", "left_foot": "LeftToe",
        "right_foot": "RightToe",
    },
    "cmu_motionbuilder": {
        "pelvis": "Hips", "spine1": "LowerBack", "spine2": "Spine", "spine3": "Spine1", "neck": "Neck",
        "head": "Head", "left_collar": "LeftShoulder", "right_collar": "RightShoulder",
        "left_shoulder": "LeftArm", "right_shoulder": "RightArm", "left_elbow": "LeftForeArm",
        "right_elbow": "RightForeArm", "left_wrist": "LeftHand", "right_wrist": "RightHand",
        "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg", "left_knee": "LeftLeg", "right_knee": "RightLeg",
        "left_ankle": "LeftFoot", "right_ankle": "RightFoot", "left_foot": "LeftToeBase",
        "right_foot": "RightToeBase",
    },
    "cmu_daz": {  # no toe joint: the foot keeps the ankle's rotation
        "pelvis": "hip", "spine1": "abdomen", "spine2": ("abdomen", "chest"), "spine3": "chest",
        "neck": "neck", "head": "head", "left_collar": "lCollar", "right_collar": "rCollar",
        "left_shoulder": "lShldr", "right_shoulder": "rShldr", "left_elbow": "lForeArm",
        "right_elbow": "rForeArm", "left_wrist": "lHand", "right_wrist": "rHand", "left_hip": "lThigh",
        "right_hip": "rThigh", "left_knee": "lShin", "right_knee": "rShin", "left_ankle": "lFoot",
        "right_ankle": "rFoot",
    },
}
# Bones whose lengths the betas are fitted to (SMPL joint pairs, both matched), with their weights: the trunk
# and the head sit less alike across skeletons than the limbs.
_SHAPE_BONES = (("left_hip", "left_knee", 1.0), ("left_knee", "left_ankle", 1.0),
                ("right_hip", "right_knee", 1.0), ("right_knee", "right_ankle", 1.0),
                ("left_ankle", "left_foot", 0.5), ("right_ankle", "right_foot", 0.5),
                ("left_shoulder", "left_elbow", 1.0), ("left_elbow", "left_wrist", 1.0),
                ("right_shoulder", "right_elbow", 1.0), ("right_elbow", "right_wrist", 1.0),
                ("left_hip", "right_hip", 0.5), ("left_shoulder", "right_shoulder", 0.5),
                ("neck", "head", 0.3), ("left_hip", "neck", 0.5), ("right_hip", "neck", 0.5))
# Lengths units the file may use (metres per unit): a limb-length scale within 12% of one snaps to it, so a
# clip's size is the performer's and not the body model's. (1 / 0.45) inch: CMU's cgspeed conversion.
_UNITS = (1.0, 0.01, 0.001, 0.0254, 0.0254 / 0.45)


@dataclass
class FastRetargetConfig:
    fps: float = 30.0                 # output frame rate (rotations slerped, positions linear)
    up_axis: str = "y"                # the BVH's up axis: "y" or "z"
    scale: float | None = None        # metres per BVH unit; None: from limb lengths, snapped to a known unit
    calibration_frames: int = 8       # frames fitted by inverse kinematics to calibrate the carried rotations
    refine_threshold_mm: float = 30.0  # frames whose matched joints miss by more than this get an IK fit
    refine_iterations: int = 15
    refine_pull: float = 0.1          # weight (m/rad) pulling a refined frame towards its carried-over pose
    shape_prior: float = 0.02         # weight (m per unit beta) of the betas' pull to zero in the bone fit
    ground_quantile: float = 0.1      # the ground touches this quantile of the per-frame lowest mesh point
    ground_frames: int = 24           # frames (spread over the clip) whose lowest mesh point sets the ground


def _slerp_rows(rot: np.ndarray, i0: np.ndarray, i1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rotations (F, D, 3, 3) interpolated between frames i0 and i1 with weights w (n,) -> (n, D, 3, 3)."""
    F, D = rot.shape[:2]
    q = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat().reshape(F, D, 4)
    qa, qb = q[i0], q[i1]
    dot = np.sum(qa * qb, axis=-1, keepdims=True)
    qb = np.where(dot < 0, -qb, qb)
    dot = np.abs(dot).clip(max=1.0)
    theta = np.arccos(dot)
    s = np.sin(theta)
    w = w[:, None, None]
    small = s < 1e-6
    wa = np.where(small, 1.0 - w, np.sin((1.0 - w) * theta) / np.where(small, 1.0, s))
    wb = np.where(small, w, np.sin(w * theta) / np.where(small, 1.0, s))
    out = wa * qa + wb * qb
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    return Rotation.from_quat(out.reshape(-1, 4)).as_matrix().reshape(len(i0), D, 3, 3)


def _mean_rotation(mats: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices (..., K, 3, 3) -> (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(mats.sum(axis=-3))
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= d[..., None]
    return U @ Vt


class _ShapeBasis:
    """The model's rest joints as an affine function of the betas: J(b) = J0 + S b (exact: no pose blend at
    rest)."""

    def __init__(self, model: BodyModel):
        zero = np.zeros((1, model.num_joints, 3))
        B = model.num_betas
        self.J0 = model.joints(zero, np.zeros(B))[0]
        self.S = np.stack([model.joints(zero, np.eye(B)[k])[0] - self.J0 for k in range(B)], axis=-1)


_BASES: dict[int, _ShapeBasis] = {}


def fit_betas_to_bones(model: BodyModel, lengths: dict[tuple[str, str], float], prior: float = 0.01,
                       weights: dict[tuple[str, str], float] | None = None,
                       iterations: int = 15) -> np.ndarray:
    """Betas whose rest skeleton has the given bone lengths (metres, keyed by SMPL joint-name pairs), by
    Gauss- Newton least squares with a pull of `prior` (metres per unit beta) towards zero."""
    basis = _BASES.get(id(model))
    if basis is None:
        basis = _BASES[id(model)] = _ShapeBasis(model)
    pairs = list(lengths)
    if not pairs:
        raise ValueError("fit_betas_to_bones needs at least one bone length")
    a = np.array([SMPL_JOINT_NAMES.index(p[0]) for p in pairs])
    b = np.array([SMPL_JOINT_NAMES.index(p[1]) for p in pairs])
    target = np.array([lengths[p] for p in pairs])
    w = np.array([(weights or {}).get(p, 1.0) for p in pairs])
    d0 = basis.J0[b] - basis.J0[a]             # (K, 3)
    dS = basis.S[b] - basis.S[a]               # (K, 3, B)
    B = model.num_betas
    betas = np.zeros(B)
    for _ in range(iterations):
        vec = d0 + dS @ betas
        length = np.linalg.norm(vec, axis=-1)
        u = vec / np.maximum(length, 1e-9)[:, None]
        J = np.concatenate([w[:, None] * np.einsum("ki,kib->kb", u, dS), prior * np.eye(B)])
        r = np.concatenate([w * (length - target), prior * betas])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        betas = betas + step
        if np.abs(step).max() < 1e-6:
            break
    return betas


def _scale(pos: np.ndarray, joint_map: dict[str, str], model: BodyModel) -> float:
    """Metres per BVH unit from the limb lengths against the model's at zero betas, snapped to a known
    unit."""
    from m3c.eval.retarget import _SCALE_BONES

    names = list(joint_map)
    rest = model.joints(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas))[0]
    bvh_len = model_len = 0.0
    for a, b in _SCALE_BONES:
        if a in names and b in names:
            model_len += np.linalg.norm(rest[SMPL_JOINT_NAMES.index(a)] - rest[SMPL_JOINT_NAMES.index(b)])
            bvh_len += np.median(np.linalg.norm(pos[:, names.index(a)] - pos[:, names.index(b)], axis=-1))
    if bvh_len <= 0:
        raise ValueError("cannot infer the BVH scale: the mapped limbs have zero length; pass scale=")
    scale = model_len / bvh_len
    for unit in _UNITS:
        if abs(np.log(scale / unit)) < np.log(1.12):
            return unit
    return scale


def _resolve_map(bvh: BVHMotion, joint_map) -> tuple[str | None, dict[str, str]]:
    if joint_map is None:
        joint_map = detect_joint_map(bvh)
    if isinstance(joint_map, str):
        if joint_map not in JOINT_MAPS:
            raise ValueError(f"unknown joint map {joint_map!r}; choose from {sorted(JOINT_MAPS)}")
        return joint_map, JOINT_MAPS[joint_map]
    unknown = set(joint_map) - set(SMPL_JOINT_NAMES)
    if unknown:
        raise ValueError(f"joint_map keys must be SMPL joint names, unknown: {sorted(unknown)}")
    return None, dict(joint_map)


def fast_retarget(model: BodyModel, bvh: BVHMotion | str | Path,
                  joint_map: dict[str, str] | str | None = None, config: FastRetargetConfig | None = None,
                  frames=None, drivers: dict[str, str | tuple[str, str]] | None = None) -> RetargetedMotion:
    """Retargets a BVH clip by carrying its rotations over (see the module docstring). joint_map: a JOINT_MAPS
    key, a dict SMPL name -> BVH joint placed alike, or None to detect it; drivers: SMPL name -> the BVH joint
    whose rotation drives it (default: DRIVER_MAPS of the convention); frames: a slice or index array of BVH
    frames. info holds the scale, the refined frame count and the time taken."""
    start_time = time.perf_counter()
    config = config or FastRetargetConfig()
    if model.num_joints != 24:
        raise ValueError(f"retargeting needs the SMPL 24-joint layout, the model has {model.num_joints} "
                         "joints")
    if config.up_axis not in _UP:
        raise ValueError(f"up_axis must be one of {sorted(_UP)}, got {config.up_axis!r}")
    if not isinstance(bvh, BVHMotion):
        bvh = read_bvh(bvh)
    convention, joint_map = _resolve_map(bvh, joint_map)
    if drivers is None:
        if convention is None:
            raise ValueError("a joint_map dict needs drivers= too (SMPL joint -> the BVH joint whose "
                             f"rotation drives it), as in DRIVER_MAPS; or pass one of {sorted(DRIVER_MAPS)}")
        drivers = DRIVER_MAPS[convention]
    if "pelvis" not in drivers:
        raise ValueError("drivers must name the BVH joint that drives the pelvis")
    driver_names = sorted({n for v in drivers.values() for n in ((v,) if isinstance(v, str) else v)})
    driver_idx = {n: bvh.index(n) for n in driver_names}
    pos_idx = [bvh.index(n) for n in joint_map.values()]

    # World rotations and positions, y up; resampled to config.fps.
    motion_frames = np.arange(bvh.num_frames)[slice(None) if frames is None else frames]
    if len(motion_frames) < 2:
        raise ValueError(f"{bvh.path}: {len(motion_frames)} frame(s); retargeting needs at least 2")
    rot, pos = bvh.world_transforms(motion_frames)
    up = _UP[config.up_axis]
    rot = up @ rot[:, [driver_idx[n] for n in driver_names]]
    pos = pos[:, pos_idx] @ up.T
    scale = _scale(pos, joint_map, model) if config.scale is None else float(config.scale)
    src_t = (motion_frames - motion_frames[0]) * bvh.frame_time
    out_t = np.arange(0.0, src_t[-1] + 1e-9, 1.0 / config.fps)
    i1 = np.clip(np.searchsorted(src_t, out_t, side="right"), 1, len(src_t) - 1)
    i0 = i1 - 1
    w = np.clip((out_t - src_t[i0]) / (src_t[i1] - src_t[i0]), 0.0, 1.0)
    targets = (pos[i0] * (1 - w)[:, None, None] + pos[i1] * w[:, None, None]) * scale
    rot = _slerp_rows(rot, i0, i1, w)
    n = len(targets)

    # Drivers' world rotations per SMPL joint (None: the parent's rotation).
    parents = np.asarray(model.parents)
    col = {name: k for k, name in enumerate(driver_names)}
    driven = np.zeros((n, 24, 3, 3))
    has_driver = np.zeros(24, dtype=bool)
    for name, src in drivers.items():
        j = SMPL_JOINT_NAMES.index(name)
        has_driver[j] = True
        if isinstance(src, str):
            driven[:, j] = rot[:, col[src]]
        else:
            driven[:, j] = _halfway(np.stack([rot[:, col[src[0]]], rot[:, col[src[1]]]], axis=1))

    # Betas from the bone lengths.
    names = list(joint_map)
    lengths, bone_w = {}, {}
    for a, b, wt in _SHAPE_BONES:
        if a in names and b in names:
            bone = targets[:, names.index(a)] - targets[:, names.index(b)]
            lengths[(a, b)] = float(np.median(np.linalg.norm(bone, axis=-1)))
            bone_w[(a, b)] = wt
    betas = fit_betas_to_bones(model, lengths, config.shape_prior, bone_w)

    # Calibrate A_j on IK fits of a few frames.
    ids = np.array([SMPL_JOINT_NAMES.index(nm) for nm in names])
    weights = np.array([JOINT_WEIGHTS.get(nm, 1.0) for nm in names])
    ik_config = RetargetConfig(max_iterations=config.refine_iterations * 2)
    fitter = _Fitter(model, ids, weights, ik_config)
    sample = np.unique(np.linspace(0, n - 1, min(config.calibration_frames, n)).round().astype(int))
    fits = np.stack([fitter.solve(fitter.initial(targets[i], betas), targets[i], betas, None)
                     for i in sample])
    fit_rot = global_rotations(fits[:, 3:].reshape(len(sample), -1, 3), parents)      # (K, 24, 3, 3)
    align = _mean_rotation(np.einsum("kjba,kjbc->jkac", driven[sample], fit_rot))     # (24, 3, 3)

    # Carry the rotations over: world rotations, then local ones.
    world = np.empty((n, 24, 3, 3))
    for j in range(24):
        if has_driver[j]:
            world[:, j] = driven[:, j] @ align[j]
        else:
            world[:, j] = world[:, parents[j]]
    local = world.copy()
    local[:, 1:] = np.einsum("njba,njbc->njac", world[:, parents[1:]], world[:, 1:])
    pose = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_rotvec().reshape(n, 24, 3)

    # Root translation and the joint offsets (mean residuals in each carrier bone's frame), alternated.
    joints = model.joints(pose, betas)[:, ids]
    carrier_rot = world[:, fitter.carrier]
    offsets = np.zeros((len(ids), 3))
    wn = weights / weights.sum()
    for _ in range(3):
        matched = joints + np.einsum("nkij,kj->nki", carrier_rot, offsets)
        transl = np.einsum("k,nki->ni", wn, targets - matched)
        resid = targets - joints - transl[:, None]
        offsets = np.einsum("nkji,nkj->ki", carrier_rot, resid) / n
    fitter.offsets = offsets
    matched = joints + np.einsum("nkij,kj->nki", carrier_rot, offsets)
    transl = np.einsum("k,nki->ni", wn, targets - matched)
    err = np.linalg.norm(matched + transl[:, None] - targets, axis=-1).mean(axis=-1) * 1000.0

    # IK only where carrying over leaves an error.
    bad = np.flatnonzero(err > config.refine_threshold_mm)
    if len(bad):
        refine = RetargetConfig(temporal=config.refine_pull, max_iterations=config.refine_iterations)
        fitter.config = refine
        for i in bad:
            x0 = np.concatenate([transl[i], pose[i].ravel()])
            x = fitter.solve(x0, targets[i], betas, x0, refreshes=1)
            xi = fitter.matched_points(x[None], betas)[0]
            e = np.linalg.norm(xi - targets[i], axis=-1).mean() * 1000.0
            if e < err[i]:
                transl[i], pose[i], err[i] = x[:3], x[3:].reshape(24, 3), e

    # Stand on y = 0: most frames' lowest mesh point touches the ground.
    few = np.unique(np.linspace(0, n - 1, max(1, min(config.ground_frames, n))).round().astype(int))
    lowest = model.forward(pose[few], betas, transl[few]).vertices[:, :, 1].min(axis=1)
    transl = transl - np.array([0.0, np.quantile(lowest, config.ground_quantile), 0.0])
    root = Rotation.from_rotvec(pose[:, 0]).as_rotvec()
    info = {"scale": scale, "joint_map": dict(joint_map), "refined_frames": len(bad),
            "seconds": time.perf_counter() - start_time, "offsets_m": offsets}
    return RetargetedMotion(config.fps, transl, root, pose[:, 1:].copy(), betas, err, str(bvh.path),
                            getattr(model.data, "name", ""), info)


def _halfway(pair: np.ndarray) -> np.ndarray:
    """The rotation halfway between pair[:, 0] and pair[:, 1] (n, 2, 3, 3) -> (n, 3, 3)."""
    rel = np.einsum("nba,nbc->nac", pair[:, 0], pair[:, 1])
    half = Rotation.from_rotvec(0.5 * Rotation.from_matrix(rel).as_rotvec()).as_matrix()
    return pair[:, 0] @ half
