"""One stage's objective of the world optimizer, written again in torch, independently of the C++ terms.

It serves two purposes: a check of the C++ terms (their costs must equal these at any state, see
tests/python/test_motion_torch_objective.py) and the SLAHMR-style baseline of bench/motion_optimizer.py
(torch L-BFGS, lr 1, max_iter 20, strong Wolfe, over the same variables as the Ceres stage).

The objective is the one Ceres minimises, 1/2 sum over the stage's terms of weight * loss (config.py lists the
losses), over the variables: per frame root translation (3), root orientation (3, axis-angle), body pose
(3(J-1)); per track betas (B); shared camera scale and offset. Constants the C++ stage fixes when it builds its
problem are fixed here at the start state in the same way: the HuMoR term's ground frame (the track's plane at
its middle frame, moved to the world with the start scale) and its per-block level c (NLL at the start - 100;
the term is weight * max(NLL - c, 0)).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from m3c.body import BodyModel
from m3c.body.torch_lbs import axis_angle_to_matrix
from m3c.motion.config import OptimizerConfig, StageSpec
from m3c.body.joint_names import CONTACT_JOINTS, SMPL_JOINT_NAMES
from m3c.motion.optimize import Cameras, Track
from m3c.perception.contacts import contact_rest_heights

TORCH_TERMS = ("reprojection", "shape_prior", "pose_prior", "latent_smoothness", "pose_anchor", "pose_smoothness",
               "joint_smoothness", "joint_acceleration", "root_acceleration", "ray_acceleration", "contact_velocity",
               "contact_height", "motion_prior", "scale_prior", "upright", "heading_anchor", "end_motion_anchor",
               "ground_penetration")
# The C++ level of each HuMoR block sits this many nats below its NLL at the stage's start.
MOTION_PRIOR_LEVEL_DROP = 100.0


class TorchPoser(torch.nn.Module):
    """Posed joints and a few posed vertices (the ones a keypoint regressor reads) of an SMPL-layout model.

    Full LBS restricted to the selected vertices: shape and pose blend shapes, forward kinematics, skinning.
    forward(pose (N, J, 3), betas (N, B), transl (N, 3)) -> (joints (N, J, 3), vertices (N, U, 3)).
    """

    def __init__(self, model: BodyModel, vertex_ids, dtype: torch.dtype = torch.float64):
        super().__init__()
        data = model.data
        ids = np.asarray(vertex_ids, dtype=np.int64)
        J = model.num_joints
        as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
        self.register_buffer("v_template", as_t(data.v_template[ids]))
        self.register_buffer("shapedirs", as_t(data.shapedirs[ids]))  # (U, 3, B)
        # (9(J-1), 3U): row 9(j-1)+3r+c multiplies (R_j - I)[r, c]
        self.register_buffer("posedirs", as_t(data.posedirs[ids].reshape(3 * len(ids), -1).T))
        self.register_buffer("weights", as_t(data.weights[ids]))  # (U, J)
        self.register_buffer("joint_template", as_t(data.J_regressor @ data.v_template))  # (J, 3)
        self.register_buffer("joint_shapedirs", as_t(np.einsum("jv,vkb->jkb", data.J_regressor, data.shapedirs)))
        self.parents = [int(p) for p in data.parents]
        self.num_joints = J

    def forward(self, pose: torch.Tensor, betas: torch.Tensor, transl: torch.Tensor):
        n, J = pose.shape[0], self.num_joints
        rest = self.joint_template + torch.einsum("nb,jkb->njk", betas, self.joint_shapedirs)
        rot = axis_angle_to_matrix(pose)  # (N, J, 3, 3)
        rel = torch.cat([rest[:, :1], rest[:, 1:] - rest[:, self.parents[1:]]], dim=1)
        world_R, world_t = [rot[:, 0]], [rel[:, 0]]
        for j in range(1, J):
            p = self.parents[j]
            world_R.append(world_R[p] @ rot[:, j])
            world_t.append((world_R[p] @ rel[:, j, :, None])[..., 0] + world_t[p])
        R = torch.stack(world_R, dim=1)
        joints = torch.stack(world_t, dim=1)
        if self.v_template.shape[0] == 0:
            return joints + transl[:, None], joints.new_zeros(n, 0, 3)
        eye = torch.eye(3, dtype=pose.dtype)
        shaped = self.v_template + torch.einsum("nb,ukb->nuk", betas, self.shapedirs)
        posed = shaped + ((rot[:, 1:] - eye).reshape(n, -1) @ self.posedirs).reshape(n, -1, 3)
        # Skinning transforms: x -> R_j (x - rest_j) + joint_j, blended by the weights.
        offset = joints - (R @ rest[..., None])[..., 0]
        blend_R = torch.einsum("uj,njab->nuab", self.weights, R)
        blend_t = torch.einsum("uj,nja->nua", self.weights, offset)
        vertices = (blend_R @ posed[..., None])[..., 0] + blend_t
        return joints + transl[:, None], vertices + transl[:, None]


@dataclass
class TorchState:
    """All variables, tracks stacked along rows: transl (N, 3), root (N, 3), body (N, 3(J-1)), betas (P, B),
    scale (), offset (3)."""

    transl: torch.Tensor
    root: torch.Tensor
    body: torch.Tensor
    betas: torch.Tensor
    scale: torch.Tensor
    offset: torch.Tensor

    GROUPS = ("transl", "root", "body", "betas", "scale", "offset")

    @classmethod
    def from_tracks(cls, tracks: list[Track], scale: float = 1.0, offset=None,
                    dtype: torch.dtype = torch.float64) -> "TorchState":
        cat = lambda xs: torch.as_tensor(np.concatenate(xs), dtype=dtype)  # noqa: E731
        return cls(cat([np.asarray(t.transl).reshape(-1, 3) for t in tracks]),
                   cat([np.asarray(t.root_orient).reshape(-1, 3) for t in tracks]),
                   cat([np.asarray(t.body_pose).reshape(t.num_frames, -1) for t in tracks]),
                   torch.as_tensor(np.stack([np.asarray(t.betas, dtype=np.float64) for t in tracks]), dtype=dtype),
                   torch.tensor(float(scale), dtype=dtype),
                   torch.as_tensor(np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64),
                                   dtype=dtype))

    def to_tracks(self, template: list[Track]) -> list[Track]:
        """Tracks with these values and the template's observations."""
        out, row = [], 0
        for i, t in enumerate(template):
            n = t.num_frames
            s = slice(row, row + n)
            out.append(replace(t, transl=self.transl[s].detach().numpy().copy(),
                               root_orient=self.root[s].detach().numpy().copy(),
                               body_pose=self.body[s].detach().numpy().reshape(n, -1, 3).copy(),
                               betas=self.betas[i].detach().numpy().copy()))
            row += n
        return out

    def detached(self) -> "TorchState":
        return TorchState(*(getattr(self, g).detach().clone() for g in self.GROUPS))


def ground_frame(normal: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform (R, t) into a z-up frame of the world plane n.x + offset = 0 (n unit): rows of R are two
    in-plane axes and n, t = (0, 0, offset), so z is the height above the plane. The in-plane axes are the
    world x (or y when n is close to x) projected onto the plane, as the C++ term chooses them; HuMoR's
    canonical frame removes the heading anyway."""
    n = normal / np.linalg.norm(normal)
    seed = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = seed - seed.dot(n) * n
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1), n]), np.array([0.0, 0.0, offset])


class StageObjective:
    """The objective of one optimizer stage as a differentiable function of a TorchState.

    model: the body model; tracks: the optimizer's inputs (observations, ground planes, contacts, and the
    start values); cameras: as for m3c.motion.optimize; stage: a StageSpec of `config`; motion_prior: a
    m3c.models.humor.HumorModel (the weights the C++ term loads; frozen here) or None (the term is then left
    out, as the C++ optimizer leaves it out); pose_prior: likewise a m3c.models.vposer VPoser module for the
    pose_prior and latent_smoothness terms, or None; keypoint_weights: (vertex_weights K x V, joint_weights K x J)
    of the keypoint regressor (default COCO-17); start: the state the stage starts from (default: the tracks'
    values with cameras.initial_scale), which fixes the HuMoR ground frames and levels.
    """

    def __init__(self, model: BodyModel, tracks: list[Track], cameras: Cameras, config: OptimizerConfig,
                 stage: StageSpec, motion_prior=None, fps: float = 30.0, keypoint_weights=None,
                 start: TorchState | None = None, dtype: torch.dtype = torch.float64, pose_prior=None):
        active = {term: float(w) for term, w in stage.weights.items() if w > 0}
        unknown = sorted(set(active) - set(TORCH_TERMS))
        if unknown:
            raise ValueError(f"stage {stage.name!r}: no torch counterpart for the terms {unknown}; "
                             f"supported: {list(TORCH_TERMS)}")
        if "motion_prior" in active and motion_prior is None:
            del active["motion_prior"]  # the C++ optimizer reports it unavailable and leaves it out
        if pose_prior is None:
            for term in ("pose_prior", "latent_smoothness"):  # VPoser terms: likewise without its weights
                active.pop(term, None)
        else:
            if config.latent_pose:
                raise ValueError("the torch objective optimises axis-angle body poses; VPoser latent poses "
                                 "(config.latent_pose) have no torch counterpart here: set latent_pose=False")
            pose_prior.eval().requires_grad_(False)
        self.pose_prior = pose_prior
        # pose_anchor's centre: the tracks' own (regressed) body pose, whatever state a stage starts from.
        self.anchor = torch.as_tensor(np.concatenate([np.asarray(t.body_pose, dtype=np.float64).reshape(
            t.num_frames, -1) for t in tracks]), dtype=dtype)
        self.stage, self.config, self.weights, self.dtype = stage, config, active, dtype
        self.free = [g for g in stage.free if not (g == "scale" and cameras.static)
                     and not (g == "offset" and not config.optimize_offset)]
        if motion_prior is not None:
            motion_prior.requires_grad_(False)  # the weights are constants here; no gradients to accumulate
        self.model, self.motion_prior, self.fps = model, motion_prior, float(fps)
        J = model.num_joints
        vw, jw = keypoint_weights if keypoint_weights is not None else model.coco17_weights()
        self.vertex_ids = np.flatnonzero(np.abs(vw).sum(0) > 0)
        self.poser = TorchPoser(model, self.vertex_ids, dtype)
        as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
        self.kp_vertex_weights = as_t(vw[:, self.vertex_ids])
        self.kp_joint_weights = as_t(jw)

        self.cameras = cameras
        world_from_cam = np.asarray(cameras.world_from_cam, dtype=np.float64)
        T = len(world_from_cam)
        intrinsics = np.asarray(cameras.intrinsics, dtype=np.float64)
        intrinsics = np.tile(intrinsics, (T, 1)) if intrinsics.shape == (4,) else intrinsics
        rows = np.concatenate([t.first_frame + np.arange(t.num_frames) for t in tracks])
        self.track_of_row = torch.as_tensor(np.concatenate([np.full(t.num_frames, i) for i, t in enumerate(tracks)]))
        self.cam_from_world = as_t(np.transpose(world_from_cam[rows, :3, :3], (0, 2, 1)))
        self.centre = as_t(world_from_cam[rows, :3, 3])
        self.intrinsics = as_t(intrinsics[rows])
        obs = np.concatenate([np.asarray(t.keypoints, dtype=np.float64).reshape(t.num_frames, -1, 3)
                              for t in tracks])
        obs[..., 2] = np.where(obs[..., 2] < config.min_confidence, 0.0, obs[..., 2])
        self.observations = as_t(obs)
        self.frames_per_track = as_t([t.num_frames for t in tracks])

        # Consecutive frames within a track: pairs (first rows of each pair) and triples.
        starts = np.cumsum([0] + [t.num_frames for t in tracks])
        self.pairs = torch.as_tensor(np.concatenate([np.arange(a, b - 1) for a, b in zip(starts[:-1], starts[1:])]))
        self.triples = torch.as_tensor(np.concatenate([np.arange(a, b - 2) for a, b in zip(starts[:-1], starts[1:])]))

        # Contact weights (probability where it reaches the threshold) and ground planes in the world.
        contacts = np.zeros((len(rows), len(CONTACT_JOINTS)))
        on_ground = np.zeros_like(contacts)  # contact_height's points: ground_contacts where given
        rest_heights = np.zeros_like(contacts)  # each contact joint's height above the sole at rest
        has_ground = np.zeros(len(rows), dtype=bool)
        normal_cam = np.tile([0.0, 0.0, 1.0], (len(rows), 1))
        offset_cam = np.zeros(len(rows))
        for t, a in zip(tracks, starts):
            s = slice(a, a + t.num_frames)
            if t.contacts is not None:
                p = np.asarray(t.contacts, dtype=np.float64).reshape(t.num_frames, -1)
                contacts[s] = np.where(p >= config.contact_threshold, p, 0.0)
                g = p if t.ground_contacts is None else np.asarray(t.ground_contacts, dtype=np.float64).reshape(
                    t.num_frames, -1)
                on_ground[s] = np.where(g >= config.contact_threshold, g, 0.0)
            rest_heights[s] = contact_rest_heights(model, t.betas)
            if t.ground_normal is not None:
                has_ground[s] = True
                normal_cam[s] = np.asarray(t.ground_normal, dtype=np.float64).reshape(-1, 3)
                offset_cam[s] = np.asarray(t.ground_offset, dtype=np.float64).reshape(-1)
        self.contact_weights = as_t(contacts)
        norm = np.linalg.norm(normal_cam, axis=1)
        self.height_weights = as_t(on_ground * has_ground[:, None])
        self.rest_heights = as_t(rest_heights)
        self.has_ground = as_t(has_ground)  # upright's rows: its up direction is the ground's normal
        self.ground_normal = as_t(np.einsum("nij,nj->ni", world_from_cam[rows, :3, :3], normal_cam) / norm[:, None])
        # heading_anchor's reference: the tracks' own root orientation's facing direction (the body's z axis)
        # across the ground normal, unit; rows whose reference faces within 15 degrees of it hold no heading.
        root = torch.as_tensor(np.concatenate([np.asarray(t.root_orient, dtype=np.float64).reshape(-1, 3)
                                               for t in tracks]), dtype=dtype)
        facing = axis_angle_to_matrix(root)[:, :, 2]
        level = facing - (facing * self.ground_normal).sum(-1, keepdim=True) * self.ground_normal
        self.heading_rows = self.has_ground * (level.norm(dim=-1) >= 0.25)
        self.heading_reference = level / level.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        self.ground_offset_cam = as_t(offset_cam / norm)

        # end_motion_anchor's steps: (row f, row g of its neighbour towards the well-seen frames, weight = the share
        # of well_seen_keypoints that f lacks, the tracks' own step T0_f - T0_g) in each track's open ends.
        end_f, end_g, end_w = [], [], []
        for t, a in zip(tracks, starts):
            kp = np.asarray(t.keypoints, dtype=np.float64).reshape(t.num_frames, -1, 3)
            seen = (kp[..., 2] >= config.min_confidence).sum(-1)
            good = np.flatnonzero(seen >= config.well_seen_keypoints)
            first, last = (good[0], good[-1]) if len(good) else (t.num_frames, -1)
            for f in range(t.num_frames):
                g = f + 1 if f < first else f - 1
                if not first <= f <= last and g < t.num_frames:  # outside, every frame lacks keypoints
                    end_f.append(a + f)
                    end_g.append(a + g)
                    end_w.append(1.0 - seen[f] / config.well_seen_keypoints)
        self.end_rows = (torch.as_tensor(end_f, dtype=torch.long), torch.as_tensor(end_g, dtype=torch.long))
        self.end_weights = as_t(np.asarray(end_w, dtype=np.float64))
        start_transl = np.concatenate([np.asarray(t.transl, dtype=np.float64).reshape(-1, 3) for t in tracks])
        self.end_steps = as_t((start_transl[end_f] - start_transl[end_g]).reshape(-1, 3))

        self.tracks = tracks
        self.track_starts = starts
        self.start = start if start is not None else TorchState.from_tracks(tracks, cameras.initial_scale,
                                                                             dtype=dtype)
        # ray_acceleration's line of sight of each triple's middle frame, fixed at the start state (as the C++ stage
        # does when it builds its problem).
        i, start = self.triples, self.start
        rays = start.transl[i + 1] - (start.scale * self.centre[i + 1] + start.offset)
        self.rays = (rays / rays.norm(dim=-1, keepdim=True)).detach()
        self.motion_blocks = []  # (rows slice, ground R, ground t, levels with NaN where a block is skipped)
        if "motion_prior" in active:
            self._fix_motion_prior(tracks, starts)

    # ---- the pieces ------------------------------------------------------------------------------------
    def posed(self, state: TorchState):
        n = state.transl.shape[0]
        pose = torch.cat([state.root[:, None], state.body.reshape(n, -1, 3)], dim=1)
        return self.poser(pose, state.betas[self.track_of_row], state.transl)

    def keypoints(self, joints: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
        return (torch.einsum("kv,nvc->nkc", self.kp_vertex_weights, vertices)
                + torch.einsum("kj,njc->nkc", self.kp_joint_weights, joints))

    def _fix_motion_prior(self, tracks, starts):
        s = self.start
        for t, a in zip(tracks, starts):
            n = t.num_frames
            if t.ground_normal is None or n < 4:
                continue
            mid = a + n // 2
            normal_cam = np.asarray(t.ground_normal, dtype=np.float64).reshape(-1, 3)[n // 2]
            offset_cam = float(np.asarray(t.ground_offset, dtype=np.float64).reshape(-1)[n // 2])
            R_wc = self.cam_from_world[mid].numpy().T
            normal = R_wc @ normal_cam / np.linalg.norm(normal_cam)
            centre = float(s.scale) * self.centre[mid].numpy() + s.offset.numpy()
            R, tr = ground_frame(normal, offset_cam / np.linalg.norm(normal_cam) - normal.dot(centre))
            block = (slice(a, a + n), torch.as_tensor(R, dtype=self.dtype), torch.as_tensor(tr, dtype=self.dtype))
            with torch.no_grad():
                joints, _ = self.posed(s)
                nll = self._transition_nll(s, joints, block)
            levels = nll - MOTION_PRIOR_LEVEL_DROP
            self.motion_blocks.append(block + (torch.where(torch.isfinite(levels), levels, torch.nan),))

    def _transition_nll(self, state: TorchState, joints: torch.Tensor, block) -> torch.Tensor:
        from m3c.models import humor_state as hs
        from m3c.models.humor import transition_nll

        rows, R, t = block
        n = rows.stop - rows.start
        states = hs.build_states(state.transl[rows], state.root[rows],
                                 state.body[rows].reshape(n, -1, 3)[:, :hs.NUM_BODY_JOINTS], joints[rows],
                                 self.fps, (R, t))
        return transition_nll(self.motion_prior, states[:-1], states[1:])

    # ---- the objective ---------------------------------------------------------------------------------
    def _standing(self, joints: torch.Tensor, state: "TorchState") -> torch.Tensor:
        """(rows, 4) each contact joint's height above its standing height on the person's ground plane, the plane
        moved to the world with the state's camera scale and offset."""
        centre = state.scale * self.centre + state.offset
        d = self.ground_offset_cam - (self.ground_normal * centre).sum(-1)
        feet = joints[:, list(CONTACT_JOINTS)]
        return (feet * self.ground_normal[:, None]).sum(-1) + d[:, None] - self.rest_heights

    def terms(self, state: TorchState) -> dict[str, torch.Tensor]:
        """Cost of every active term (1/2 weight loss), as the C++ stage report gives them."""
        joints, vertices = self.posed(state)
        out = {}
        for term, w in self.weights.items():
            if term == "reprojection":
                kp = self.keypoints(joints, vertices)
                centre = state.scale * self.centre + state.offset
                xc = torch.einsum("nij,nkj->nki", self.cam_from_world, kp - centre[:, None])
                fx, fy, cx, cy = self.intrinsics.unbind(-1)
                u = fx[:, None] * xc[..., 0] / xc[..., 2] + cx[:, None]
                v = fy[:, None] * xc[..., 1] / xc[..., 2] + cy[:, None]
                r2 = (u - self.observations[..., 0]) ** 2 + (v - self.observations[..., 1]) ** 2
                s2 = self.config.robust_sigma ** 2
                conf = self.observations[..., 2]
                # Unobserved keypoints have zero weight; keep their (possibly non-finite) projection out of the sum.
                gm = torch.where(conf > 0, s2 * r2 / (s2 + r2), torch.zeros_like(r2))
                out[term] = 0.5 * w * (conf ** 2 * gm).sum()
            elif term == "shape_prior":
                out[term] = 0.5 * w * (self.frames_per_track * (state.betas ** 2).sum(-1)).sum()
            elif term == "scale_prior":
                sigma = self.cameras.scale_sigma
                out[term] = (0.5 * w * ((torch.log(state.scale) - np.log(self.cameras.initial_scale)) / sigma) ** 2
                             if sigma is not None and np.isfinite(sigma) and sigma > 0 else state.scale.new_zeros(()))
            elif term == "pose_anchor":
                out[term] = 0.5 * w * ((state.body - self.anchor) ** 2).sum()
            elif term in ("pose_prior", "latent_smoothness"):
                # VPoser's encoder mean of body joints 1..21 (the first 63 body-pose values).
                dtype = next(self.pose_prior.parameters()).dtype
                z = self.pose_prior.encode(state.body[:, :63].to(dtype))[0].to(self.dtype)
                if term == "pose_prior":
                    out[term] = 0.5 * w * (z ** 2).sum()
                else:
                    out[term] = 0.5 * w * ((z[self.pairs + 1] - z[self.pairs]) ** 2).sum()
            elif term == "pose_smoothness":
                out[term] = 0.5 * w * ((state.body[self.pairs + 1] - state.body[self.pairs]) ** 2).sum()
            elif term == "joint_smoothness":
                out[term] = 0.5 * w * ((joints[self.pairs + 1] - joints[self.pairs]) ** 2).sum()
            elif term == "joint_acceleration":
                i = self.triples
                out[term] = 0.5 * w * ((joints[i + 2] - 2 * joints[i + 1] + joints[i]) ** 2).sum()
            elif term == "root_acceleration":
                i, pelvis = self.triples, joints[:, 0]
                out[term] = 0.5 * w * ((pelvis[i + 2] - 2 * pelvis[i + 1] + pelvis[i]) ** 2).sum()
            elif term == "ray_acceleration":  # the pelvis joint, which the C++ term reads as the root translation
                i, pelvis = self.triples, joints[:, 0]
                acc = pelvis[i + 2] - 2 * pelvis[i + 1] + pelvis[i]
                out[term] = 0.5 * w * ((acc * self.rays).sum(-1) ** 2).sum()
            elif term == "contact_velocity":
                feet = joints[:, list(CONTACT_JOINTS)]
                step = ((feet[self.pairs + 1] - feet[self.pairs]) ** 2).sum(-1)
                sigma = self.config.contact_velocity_sigma
                if sigma > 0:  # the robust form: sigma^2 s / (sigma^2 + s)
                    step = sigma ** 2 * step / (sigma ** 2 + step)
                out[term] = 0.5 * w * (self.contact_weights[self.pairs] * step).sum()
            elif term == "contact_height":
                excess = torch.clamp(self._standing(joints, state).abs() - self.config.contact_height_tolerance,
                                     min=0.0)
                out[term] = 0.5 * w * (self.height_weights * excess ** 2).sum()
            elif term == "ground_penetration":
                sunk = torch.clamp(-self._standing(joints, state), min=0.0)
                out[term] = 0.5 * w * (self.has_ground[:, None] * sunk ** 2).sum()
            elif term == "upright":
                spine = joints[:, SMPL_JOINT_NAMES.index("neck")] - joints[:, SMPL_JOINT_NAMES.index("pelvis")]
                up = self.ground_normal
                across = ((spine - (spine * up).sum(-1, keepdim=True) * up) ** 2).sum(-1)
                s2 = self.config.upright_sigma ** 2
                out[term] = 0.5 * w * (self.has_ground * s2 * across / (s2 + across)).sum()
            elif term == "heading_anchor":
                facing = axis_angle_to_matrix(state.root)[:, :, 2]
                up = self.ground_normal
                level = facing - (facing * up).sum(-1, keepdim=True) * up
                turn = torch.atan2((torch.linalg.cross(self.heading_reference, level) * up).sum(-1),
                                   (self.heading_reference * level).sum(-1))
                out[term] = 0.5 * w * (self.heading_rows * turn ** 2).sum()
            elif term == "end_motion_anchor":
                f, g = self.end_rows
                steps = state.transl[f] - state.transl[g] - self.end_steps
                out[term] = 0.5 * w * (self.end_weights * (steps ** 2).sum(-1)).sum()
            elif term == "motion_prior":
                total = joints.new_zeros(())
                for rows, R, t, levels in self.motion_blocks:
                    nll = self._transition_nll(state, joints, (rows, R, t))
                    keep = torch.isfinite(levels)
                    total = total + torch.clamp(nll[keep] - levels[keep], min=0.0).sum()
                out[term] = 0.5 * w * total
        return out

    def __call__(self, state: TorchState) -> torch.Tensor:
        values = list(self.terms(state).values())
        return sum(values[1:], values[0]) if values else torch.zeros((), dtype=self.dtype)


@dataclass
class LbfgsRun:
    """What a torch L-BFGS run did: final objective, wall time, objective evaluations, L-BFGS steps (each up to
    max_iter inner iterations), and the first time an evaluated state reached the target (None: never)."""

    state: TorchState
    final: float
    seconds: float
    evaluations: int
    steps: int
    seconds_to_target: float | None
    stopped: str
    trace: list[tuple[float, float]] = field(default_factory=list)  # (seconds, best objective so far)


def run_lbfgs(objective: StageObjective, start: TorchState, target: float | None = None,
              time_limit: float = 60.0, max_steps: int | None = None, lr: float = 1.0,
              max_iter: int = 20) -> LbfgsRun:
    """SLAHMR's optimiser on the stage's free variables: torch.optim.LBFGS(lr 1, max_iter 20, strong Wolfe),
    step() repeated until an evaluated state reaches `target`, the time limit passes, max_steps steps are done,
    or a step no longer lowers the objective. Times include building the problem's tensors."""
    t0 = time.perf_counter()
    state = start.detached()
    params = []
    for g in objective.free:
        getattr(state, g).requires_grad_(True)
        params.append(getattr(state, g))
    if not params:
        raise ValueError(f"stage {objective.stage.name!r} frees no variables")
    optimizer = torch.optim.LBFGS(params, lr=lr, max_iter=max_iter, line_search_fn="strong_wolfe")
    best = math.inf
    evaluations = 0
    reached: list[float] = []
    trace: list[tuple[float, float]] = []

    def closure():
        nonlocal best, evaluations
        optimizer.zero_grad()
        loss = objective(state)
        loss.backward()
        evaluations += 1
        value = float(loss.detach())
        if value < best:
            best = value
            trace.append((time.perf_counter() - t0, value))
        if target is not None and not reached and value <= target:
            reached.append(time.perf_counter() - t0)
        return loss

    steps, stopped, previous = 0, "", math.inf
    while True:
        optimizer.step(closure)
        steps += 1
        if reached:
            stopped = "reached the target"
        elif time.perf_counter() - t0 > time_limit:
            stopped = f"time limit {time_limit:.0f} s"
        elif max_steps is not None and steps >= max_steps:
            stopped = f"{max_steps} steps"
        elif math.isfinite(previous) and not best < previous - 1e-12 * abs(previous):
            stopped = "no further progress"
        if stopped:
            break
        previous = best
    with torch.no_grad():
        final = float(objective(state))
    return LbfgsRun(state.detached(), final, time.perf_counter() - t0, evaluations, steps,
                    reached[0] if reached else None, stopped, trace)
