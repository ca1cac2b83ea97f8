"""Retargeting BVH motion capture onto the body model's 24 SMPL-layout joints by inverse kinematics.

The BVH skeleton and the body model disagree in proportions and in where some joints sit, so the fit matches
the joints both skeletons define alike (hips, knees, ankles, toe bases, shoulders, elbows, wrists, neck base,
head) after normalising the BVH (up axis to +y, file units to metres by the ratio of limb lengths), and
leaves the rest (spine, collars, hands, twist about the bones) to a weak pull towards the rest pose and
towards the previous frame. Per frame it solves for the root translation, root orientation and 23 joint
rotations with Levenberg-Marquardt on the C++ core's analytic joint Jacobians (BodyModel.joints_jacobian);
the shape (betas) is fitted once, alternating with the poses of a few frames spread over the clip. The result
stands on the ground plane y = 0: the lowest mesh point of most frames touches it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.io.bvh import BVHMotion, read_bvh

# SMPL joint -> BVH joint, per naming convention. Only joints placed alike on both skeletons appear.
JOINT_MAPS = {
    "cmu_3dsmax": {  # CMU via the cgspeed converter, 3dsMax-friendly names (e.g. 131_01.bvh)
        "left_hip": "LeftHip", "right_hip": "RightHip", "left_knee": "LeftKnee", "right_knee": "RightKnee",
        "left_ankle": "LeftAnkle", "right_ankle": "RightAnkle", "left_foot": "LeftToe", "right_foot": "RightToe",
        "neck": "lowerneck", "head": "Head", "left_shoulder": "LeftShoulder", "right_shoulder": "RightShoulder",
        "left_elbow": "LeftElbow", "right_elbow": "RightElbow", "left_wrist": "LeftWrist",
        "right_wrist": "RightWrist",
    },
    "cmu_motionbuilder": {  # CMU with MotionBuilder-friendly names (e.g. 01_01.bvh)
        "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg", "left_knee": "LeftLeg", "right_knee": "RightLeg",
        "left_ankle": "LeftFoot", "right_ankle": "RightFoot", "left_foot": "LeftToeBase",
        "right_foot": "RightToeBase", "neck": "Neck", "head": "Head", "left_shoulder": "LeftArm",
        "right_shoulder": "RightArm", "left_elbow": "LeftForeArm", "right_elbow": "RightForeArm",
        "left_wrist": "LeftHand", "right_wrist": "RightHand",
    },
    "bandai_namco": {  # Bandai Namco Research Motiondataset
        "left_hip": "UpperLeg_L", "right_hip": "UpperLeg_R", "left_knee": "LowerLeg_L", "right_knee": "LowerLeg_R",
        "left_ankle": "Foot_L", "right_ankle": "Foot_R", "left_foot": "Toes_L", "right_foot": "Toes_R",
        "neck": "Neck", "head": "Head", "left_shoulder": "UpperArm_L", "right_shoulder": "UpperArm_R",
        "left_elbow": "LowerArm_L", "right_elbow": "LowerArm_R", "left_wrist": "Hand_L", "right_wrist": "Hand_R",
    },
    "cmu_daz": {  # CMU via the cgspeed converter, Daz/Poser-friendly names (ROOT hip); no toe joint: the foot's
        # End Site is the toe
        "left_hip": "lThigh", "right_hip": "rThigh", "left_knee": "lShin", "right_knee": "rShin",
        "left_ankle": "lFoot", "right_ankle": "rFoot", "left_foot": "lFoot_end", "right_foot": "rFoot_end",
        "neck": "neck", "head": "head", "left_shoulder": "lShldr", "right_shoulder": "rShldr",
        "left_elbow": "lForeArm", "right_elbow": "rForeArm", "left_wrist": "lHand", "right_wrist": "rHand",
    },
}
# Neck and head joints sit less alike across skeletons than the limb joints: they count less.
JOINT_WEIGHTS = {"neck": 0.5, "head": 0.5}
# Rigid limb segments whose summed lengths set the metres-per-unit scale (no spine: its length bends).
_SCALE_BONES = (("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("right_hip", "right_knee"),
                ("right_knee", "right_ankle"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
                ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"))
_UP = {"y": np.eye(3), "z": Rotation.from_euler("x", -90, degrees=True).as_matrix()}  # z-up -> y-up


def detect_joint_map(bvh: BVHMotion) -> str:
    """The JOINT_MAPS convention whose joint names the file has."""
    names = set(bvh.names)
    for key, mapping in JOINT_MAPS.items():
        if set(mapping.values()) <= names:
            return key
    raise ValueError(f"{bvh.path}: no known joint naming ({', '.join(JOINT_MAPS)}); pass joint_map= a dict "
                     f"from SMPL joint names to this file's joints, which are {bvh.names}")


@dataclass
class RetargetConfig:
    fps: float = 30.0                 # output frame rate (the BVH is resampled by linear interpolation)
    up_axis: str = "y"                # the BVH's up axis: "y" or "z"
    scale: float | None = None        # metres per BVH unit; None: from limb lengths, refined with the shape
    pose_prior: float = 0.03          # residual weight on each body rotation (metres per radian)
    temporal: float = 0.1             # residual weight on the change from the previous frame's pose
    shape_prior: float = 0.05         # residual weight on betas (metres per unit beta)
    shape_frames: int = 12            # frames used to fit betas
    shape_rounds: int = 3             # alternations of poses and betas
    fit_shape: bool = True
    calibrate_offsets: bool = True    # per-joint offsets for joints the two skeletons place differently
    refine_scale: bool = True         # refine the limb-length scale by the fit on held-out frames
    max_iterations: int = 50
    ground_quantile: float = 0.1      # the ground touches this quantile of the per-frame lowest mesh point


@dataclass
class RetargetedMotion:
    """Body-model parameters of a retargeted clip: world frame y up, ground y = 0, metres, `fps` frames/s."""

    fps: float
    transl: np.ndarray        # (n, 3)
    root_orient: np.ndarray   # (n, 3) axis-angle
    body_pose: np.ndarray     # (n, 23, 3) axis-angle
    betas: np.ndarray         # (B,)
    fit_error_mm: np.ndarray  # (n,) mean distance of the matched body points to the BVH joints, mm
    source: str = ""
    body_model: str = ""
    info: dict = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return len(self.transl)

    def pose(self) -> np.ndarray:
        return np.concatenate([self.root_orient[:, None], self.body_pose], axis=1)

    def save(self, path: str | Path) -> None:
        from m3c.io import save_npz_atomic

        save_npz_atomic(path, fps=np.float32(self.fps), transl=self.transl.astype(np.float32),
                        root_orient=self.root_orient.astype(np.float32),
                        body_pose=self.body_pose.astype(np.float32), betas=self.betas.astype(np.float32),
                        fit_error_mm=self.fit_error_mm.astype(np.float32), source=np.array(self.source),
                        body_model=np.array(self.body_model))

    @classmethod
    def load(cls, path: str | Path) -> "RetargetedMotion":
        with np.load(path) as z:
            missing = {"fps", "transl", "root_orient", "body_pose", "betas"} - set(z.files)
            if missing:
                raise ValueError(f"{path}: not a retargeted motion file, missing {sorted(missing)}")
            return cls(float(z["fps"]), z["transl"].astype(np.float64), z["root_orient"].astype(np.float64),
                       z["body_pose"].astype(np.float64), z["betas"].astype(np.float64),
                       z["fit_error_mm"].astype(np.float64) if "fit_error_mm" in z.files
                       else np.zeros(len(z["transl"])),
                       str(z["source"]) if "source" in z.files else "",
                       str(z["body_model"]) if "body_model" in z.files else "", {"name": Path(path).stem})


def bvh_targets(bvh: BVHMotion, joint_map: dict[str, str], config: RetargetConfig, model: BodyModel,
                frames=None) -> tuple[np.ndarray, float]:
    """Target positions (n, len(joint_map), 3) in metres, y up, resampled to config.fps, and the scale
    used."""
    if config.up_axis not in _UP:
        raise ValueError(f"up_axis must be one of {sorted(_UP)}, got {config.up_axis!r}")
    idx = [bvh.index(name) for name in joint_map.values()]
    pos = bvh.positions(frames)[:, idx] @ _UP[config.up_axis].T
    if config.scale is None:
        names = list(joint_map)
        rest = model.joints(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas))[0]
        smpl = {n: rest[SMPL_JOINT_NAMES.index(n)] for n in names}
        bvh_len = model_len = 0.0
        for a, b in _SCALE_BONES:
            if a in smpl and b in smpl:
                model_len += np.linalg.norm(smpl[a] - smpl[b])
                bvh_len += np.median(np.linalg.norm(pos[:, names.index(a)] - pos[:, names.index(b)], axis=-1))
        if bvh_len <= 0:
            raise ValueError("cannot infer the BVH scale: the mapped limbs have zero length; pass scale=")
        scale = model_len / bvh_len
    else:
        scale = float(config.scale)
    pos = pos * scale
    # Resample to the output rate (linear in time, per joint coordinate; strided frame selections keep their
    # times).
    frame_ids = np.arange(bvh.num_frames)[slice(None) if frames is None else frames]
    src_t = (frame_ids - frame_ids[0]) * bvh.frame_time
    out_t = np.arange(0.0, src_t[-1] + 1e-9, 1.0 / config.fps)
    flat = pos.reshape(len(pos), -1)
    resampled = np.stack([np.interp(out_t, src_t, flat[:, k]) for k in range(flat.shape[1])], axis=1)
    return resampled.reshape(len(out_t), -1, 3), scale


def levenberg_marquardt(fun, x0: np.ndarray, max_iterations: int = 50, rtol: float = 1e-10) -> np.ndarray:
    """Minimises 1/2 |r(x)|^2 with Levenberg-Marquardt (Marquardt's diagonal scaling); fun(x) -> (r, dr/dx).
    Small dense problems (tens of parameters) solve faster here than through MINPACK's QR."""
    x = np.asarray(x0, dtype=np.float64).copy()
    r, J = fun(x)
    cost = r @ r
    damping = 1e-4
    for _ in range(max_iterations):
        g = J.T @ r
        H = J.T @ J
        diag = np.diag(H).copy()
        diag[diag < 1e-12] = 1e-12
        while True:
            try:
                step = np.linalg.solve(H + damping * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            r_new, J_new = fun(x + step)
            cost_new = r_new @ r_new
            if cost_new < cost:
                break
            damping *= 10.0
            if damping > 1e10:
                return x  # no step decreases the cost: a minimum to working precision
        decrease = cost - cost_new
        x, r, J, cost = x + step, r_new, J_new, cost_new
        damping = max(damping * 0.3, 1e-9)
        if decrease <= rtol * max(cost, 1e-30) or np.abs(step).max() < 1e-12:
            break
    return x


def global_rotations(pose: np.ndarray, parents) -> np.ndarray:
    """World rotation matrices (n, J, 3, 3) of every joint for axis-angle poses (n, J, 3)."""
    local = Rotation.from_rotvec(pose.reshape(-1, 3)).as_matrix().reshape(*pose.shape[:2], 3, 3)
    out = np.empty_like(local)
    for j, p in enumerate(parents):
        out[:, j] = local[:, j] if p < 0 else out[:, p] @ local[:, j]
    return out


class _Fitter:
    """Per-frame IK residuals and their analytic Jacobian for one set of matched joints.

    Each BVH joint is matched to a body point = the SMPL joint plus a constant offset in the frame of the bone
    that carries it (the joint's parent bone; the head's own): the offsets absorb where the two skeletons
    place a joint differently (calibrated on a few frames), so that those differences do not bend the fitted
    pose.
    The offset term is held fixed within one solve and refreshed between solves.
    """

    def __init__(self, model: BodyModel, smpl_ids: np.ndarray, weights: np.ndarray, config: RetargetConfig):
        self.model = model
        self.ids = smpl_ids
        self.w = weights
        self.config = config
        self.nparam = 3 + 3 * model.num_joints
        parents = np.asarray(model.parents)
        self.carrier = np.array([j if SMPL_JOINT_NAMES[j] == "head" else parents[j] for j in smpl_ids])
        self.offsets = np.zeros((len(smpl_ids), 3))
        self.rows = (3 * smpl_ids[:, None] + np.arange(3)).ravel()
        nb = self.nparam - 6
        self.prior_jacobian = np.zeros((nb, self.nparam))
        self.prior_jacobian[:, 6:] = config.pose_prior * np.eye(nb)

    def offset_points(self, x) -> np.ndarray:
        """The matched points' offsets from their SMPL joints, in the world frame, for parameters x."""
        G = global_rotations(x[3:].reshape(1, -1, 3), self.model.parents)[0]
        return np.einsum("kij,kj->ki", G[self.carrier], self.offsets)

    def residuals_and_jacobian(self, x, target, betas, prev):
        joints, jac = self.model.joints_jacobian(x[3:].reshape(1, -1, 3), betas, x[:3])
        w3 = np.repeat(self.w, 3)
        r = [(joints[0, self.ids] - target).ravel() * w3, self.config.pose_prior * x[6:]]
        J = [jac[0, self.rows, : self.nparam] * w3[:, None], self.prior_jacobian]
        if prev is not None:
            r.append(self.config.temporal * (x[6:] - prev[6:]))
            J.append(self.prior_jacobian * (self.config.temporal / self.config.pose_prior))
        return np.concatenate(r), np.concatenate(J)

    def solve(self, x0, target, betas, prev, refreshes: int = 2):
        x = x0.copy()
        for _ in range(refreshes):
            # Keep the root axis-angle in its principal range, far from the |theta| = 2 pi singularity.
            x[3:6] = Rotation.from_rotvec(x[3:6]).as_rotvec()
            shifted = target - self.offset_points(x)
            x = levenberg_marquardt(lambda v: self.residuals_and_jacobian(v, shifted, betas, prev), x,
                                    self.config.max_iterations)
        return x

    def calibrate(self, xs, targets, betas):
        """Offsets (in each carrier bone's frame) that best explain the residuals of the given fits."""
        local = []
        for x, tgt in zip(xs, targets):
            G = global_rotations(x[3:].reshape(1, -1, 3), self.model.parents)[0][self.carrier]
            joints = self.model.joints(x[3:].reshape(1, -1, 3), betas, x[:3])[0, self.ids]
            local.append(np.einsum("kji,kj->ki", G, tgt - joints))
        self.offsets = np.mean(local, axis=0)

    def matched_points(self, params, betas) -> np.ndarray:
        """(n, K, 3) body points matched to the BVH joints for parameters (n, nparam)."""
        pose = params[:, 3:].reshape(len(params), -1, 3)
        joints = self.model.joints(pose, betas, params[:, :3])[:, self.ids]
        G = global_rotations(pose, self.model.parents)[:, self.carrier]
        return joints + np.einsum("nkij,kj->nki", G, self.offsets)

    def initial(self, target, betas):
        """Root orientation and translation from the matched joints (Kabsch), body at rest."""
        rest = self.model.joints(np.zeros((1, self.model.num_joints, 3)), betas)[0, self.ids]
        R = _kabsch(rest, target)
        x = np.zeros(self.nparam)
        x[3:6] = Rotation.from_matrix(R).as_rotvec()
        x[:3] = target.mean(0) - rest.mean(0) @ R.T
        return x


def _kabsch(src, dst):
    a = src - src.mean(0)
    b = dst - dst.mean(0)
    U, _, Vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(U @ Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def _fit_betas(model, fitter: _Fitter, xs, targets, betas, config):
    """Betas for fixed poses of a few frames: data residuals over those frames plus the shape prior."""
    B = model.num_betas
    targets = [tgt - fitter.offset_points(x) for x, tgt in zip(xs, targets)]
    w3 = np.repeat(fitter.w, 3)[:, None]
    rows = (3 * fitter.ids[:, None] + np.arange(3)).ravel()

    def residuals_and_jacobian(b):
        r, J = [], []
        for x, tgt in zip(xs, targets):
            joints, jac = model.joints_jacobian(x[3:].reshape(1, -1, 3), b, x[:3])
            r.append(((joints[0, fitter.ids] - tgt) * fitter.w[:, None]).ravel())
            J.append(jac[0, rows, fitter.nparam:] * w3)
        return np.concatenate(r + [config.shape_prior * b]), np.concatenate(J + [config.shape_prior * np.eye(B)])

    return levenberg_marquardt(residuals_and_jacobian, betas, config.max_iterations)


def _shape_stage(model, fitter: _Fitter, targets, sample, config) -> np.ndarray:
    """Betas (and the fitter's joint offsets) from alternating fits on the sampled frames; returns betas."""
    betas = np.zeros(model.num_betas)
    fitter.offsets = np.zeros_like(fitter.offsets)
    xs = [fitter.solve(fitter.initial(targets[i], betas), targets[i], betas, None) for i in sample]
    for _ in range(config.shape_rounds):
        betas = _fit_betas(model, fitter, xs, targets[sample], betas, config)
        if config.calibrate_offsets:
            fitter.calibrate(xs, targets[sample], betas)
        xs = [fitter.solve(x, targets[i], betas, None) for x, i in zip(xs, sample)]
    return betas


def _held_out_error(fitter: _Fitter, targets, frames, betas) -> float:
    """Mean matched-point error (m) of independent per-frame fits on frames the shape was not fitted to."""
    errors = []
    for i in frames:
        x = fitter.solve(fitter.initial(targets[i], betas), targets[i], betas, None)
        errors.append(np.linalg.norm(fitter.matched_points(x[None], betas)[0] - targets[i], axis=-1).mean())
    return float(np.mean(errors))


def retarget(model: BodyModel, bvh: BVHMotion | str | Path, joint_map: dict[str, str] | str | None = None,
             config: RetargetConfig | None = None, frames=None) -> RetargetedMotion:
    """Fits the body model to a BVH clip. joint_map: a JOINT_MAPS key, a dict SMPL name -> BVH name, or None to
    detect it; frames: a slice or index array of BVH frames (e.g. slice(1, None) drops CMU's added T-pose)."""
    config = config or RetargetConfig()
    if model.num_joints != 24:
        raise ValueError(f"retargeting needs the SMPL 24-joint layout, the model has {model.num_joints} joints")
    if not isinstance(bvh, BVHMotion):
        bvh = read_bvh(bvh)
    if joint_map is None:
        joint_map = detect_joint_map(bvh)
    if isinstance(joint_map, str):
        if joint_map not in JOINT_MAPS:
            raise ValueError(f"unknown joint map {joint_map!r}; choose from {sorted(JOINT_MAPS)} or pass a dict")
        joint_map = JOINT_MAPS[joint_map]
    unknown = set(joint_map) - set(SMPL_JOINT_NAMES)
    if unknown:
        raise ValueError(f"joint_map keys must be SMPL joint names, unknown: {sorted(unknown)}")
    targets, scale = bvh_targets(bvh, joint_map, config, model, frames)
    ids = np.array([SMPL_JOINT_NAMES.index(n) for n in joint_map])
    weights = np.array([JOINT_WEIGHTS.get(n, 1.0) for n in joint_map])
    fitter = _Fitter(model, ids, weights, config)
    n = len(targets)
    betas = np.zeros(model.num_betas)

    if config.fit_shape and n > 0:
        sample = np.unique(np.linspace(0, n - 1, min(config.shape_frames, n)).round().astype(int))
        if config.scale is None and config.refine_scale and n > 1:
            # The limb-length scale is only a start: skeletons differ in proportions, so pick the factor whose
            # shape fit explains held-out frames best (1-D bounded search on the log factor).
            # (A lighter shape stage inside the search: fewer frames and rounds.)
            quick = replace(config, shape_rounds=2)
            few = sample[:: max(1, len(sample) // 6)]
            held_out = np.unique(np.clip(few[:-1] + np.diff(few) // 2, 0, n - 1))

            def held_out_error(log_factor):
                scaled = targets * np.exp(log_factor)
                return _held_out_error(fitter, scaled, held_out, _shape_stage(model, fitter, scaled, few, quick))

            best = minimize_scalar(held_out_error, bounds=(np.log(0.8), np.log(1.25)), method="bounded",
                                   options={"xatol": 1e-3})
            targets = targets * np.exp(best.x)
            scale *= float(np.exp(best.x))
        betas = _shape_stage(model, fitter, targets, sample, config)

    params = np.zeros((n, fitter.nparam))
    prev = None
    for i in range(n):
        x0 = fitter.initial(targets[i], betas) if prev is None else prev
        params[i] = fitter.solve(x0, targets[i], betas, prev)
        prev = params[i]

    transl = params[:, :3]
    pose = params[:, 3:].reshape(n, -1, 3)
    err = np.linalg.norm(fitter.matched_points(params, betas) - targets, axis=-1).mean(axis=-1) * 1000.0

    # Stand on y = 0: most frames' lowest mesh point touches the ground (jumps and swings lift it).
    lowest = model.forward(pose, betas, transl).vertices[:, :, 1].min(axis=1)
    transl = transl - np.array([0.0, np.quantile(lowest, config.ground_quantile), 0.0])
    root = np.array([Rotation.from_rotvec(r).as_rotvec() for r in pose[:, 0]])
    return RetargetedMotion(config.fps, transl, root, pose[:, 1:].copy(), betas, err, str(bvh.path),
                            getattr(model.data, "name", ""),
                            {"scale": scale, "joint_map": dict(joint_map), "offsets_m": fitter.offsets.copy()})
