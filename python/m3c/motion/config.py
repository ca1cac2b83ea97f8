"""Configuration of the staged world-frame optimization, mirrored in YAML. The defaults come from the C++ core
(one definition of the recipe, DefaultOptimizerConfig in cpp/motion/world_optimizer.cc, which explains each
choice): the thesis's stages with SLAHMR's weights, except that joints are smoothed by their acceleration
(also in the root stages) instead of their velocity, and the body pose is held by pose_anchor (plus VPoser's
pose_prior when VPoser weights are given) instead of an L2 pull towards the T-pose.

Each stage frees some parameter groups (transl, root, body, betas, scale, offset) and minimises
1/2 * sum over its terms of weight * loss:
  reprojection      sum_k conf_k^2 GM(|pi(x_k) - u_k|^2), GM(s) = sigma^2 s / (sigma^2 + s), pixels
  shape_prior       n_frames * |betas|^2 per person
  pose_anchor       |body pose_t - initial body pose_t|^2 per frame (axis-angle): a Gaussian around the
                    regressed pose, which is per-frame evidence; unlike |body pose|^2 it does not pull
                    towards the T-pose
  heading_anchor    angle^2 per frame: the turn, about the person's ground normal, of the body's facing direction
                    (its z axis, projected across the normal) from the initial (regressed) one: the camera-local
                    fit sees which way a person faces where the keypoints barely do (one side hidden); the lean
                    is left to the keypoints and "upright". No residual where the initial facing direction is
                    within 15 degrees of the normal (lying down)
  pose_smoothness   |body pose_{t+1} - body pose_t|^2 (axis-angle)
  joint_smoothness  sum_j |J_{t+1} - J_t|^2 over all joints, metres (first order, as SLAHMR and the thesis;
                    it also penalises real motion)
  joint_acceleration sum_j |J_{t+1} - 2 J_t + J_{t-1}|^2 (second order: no pull towards standing still)
  root_acceleration |P_{t+1} - 2 P_t + P_{t-1}|^2 of the pelvis joint P alone (the body's depth along the camera
                    ray, which the images barely hold, without stiffening the limbs)
  ray_acceleration  (r_t . (P_{t+1} - 2 P_t + P_{t-1}))^2: the pelvis's acceleration along r_t, the unit line of
                    sight from frame t's camera to the person at the stage's start: the depth the images barely
                    hold, leaving the motion across the line of sight to them
  contact_velocity  sum_feet c |x_{t+1} - x_t|^2 where contact probability c >= contact_threshold; with
                    contact_velocity_sigma > 0 (metres per frame step) robust, c GM(|x_{t+1} - x_t|^2), so that a
                    foot wrongly labelled planted (a swing) pulls with a bounded force
  contact_height    sum_feet c max(0, |n.x + d - h| - contact_height_tolerance)^2 against the person's ground, h
                    the joint's standing height (above the sole in the rest pose: ankle about 7 cm, toes 2.5;
                    m3c.perception.contacts.contact_rest_heights), c the probabilities of Track.ground_contacts
                    (the feet surely on the ground) where given, else of its contacts
  ground_penetration sum_t sum_feet max(0, h - (n.x + d))^2 over every frame with a ground plane: no contact
                    joint below its standing height (a foot through the floor), planted or not
  upright           sum_t GM(|P (N_t - R_t)|^2), GM(s) = sigma^2 s / (sigma^2 + s), sigma = upright_sigma metres:
                    the pelvis-to-neck vector N_t - R_t across the person's ground normal (P projects onto the
                    ground's plane), the spine's lean off the vertical, robust so that a person bending over pulls
                    with a bounded force
  end_motion_anchor sum_f lack_f |(T_f - T_g) - (T0_f - T0_g)|^2 over a track's open ends, the frames f before its
                    first and after its last well-seen frame (well_seen_keypoints keypoints of confidence >=
                    min_confidence), g the neighbour towards the well-seen frames, T the root translation, T0 the
                    lift's, lack_f = 1 - (f's keypoints) / well_seen_keypoints: there the acceleration terms alone
                    would continue the well-seen frames' motion at constant velocity; the lift's steps hold it
  scale_prior       ((log s - log s0) / sigma)^2: the camera scale s held to the scale estimator's s0 within its
                    uncertainty sigma (Cameras.initial_scale, scale_sigma; no residual without sigma)
Terms that need network weights (`optimize(pose_prior=..., motion_prior=...)`; a stage reports them
unavailable otherwise and runs without them):
  pose_prior        |z_t|^2, z_t frame t's VPoser latent (latent_pose, SLAHMR's pose variables) or, with
                    latent_pose False, the VPoser encoder mean of its axis-angle body joints 1..21
  latent_smoothness |z_{t+1} - z_t|^2 (the thesis's stage (iv) latent smoothness)
  motion_prior      the HuMoR transition term (all transitions evaluated as one batch per evaluation point)
Bone-length consistency needs no term: one betas per track gives every bone one length over the whole track.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import yaml

from m3c import _core

PARAMETER_GROUPS = ("transl", "root", "body", "betas", "scale", "offset")
MINIMIZERS = ("m3c", "ceres")  # OptimizerConfig.minimizer


@dataclass
class StageSpec:
    name: str
    free: list[str]
    weights: dict[str, float]
    max_iterations: int = 20


@dataclass
class OptimizerConfig:
    robust_sigma: float = 100.0
    min_confidence: float = 0.4
    contact_threshold: float = 0.5
    contact_height_tolerance: float = 0.03
    contact_velocity_sigma: float = 0.02
    upright_sigma: float = 0.2
    min_depth: float = 0.05
    well_seen_keypoints: int = 12
    optimize_offset: bool = False
    # After each stage the world check (these terms at these weights over every person and frame) is compared
    # with its value before; a stage that raised it by more than max_world_increase (relative) is reverted.
    world_check: dict[str, float] = field(default_factory=dict)
    max_world_increase: float = 0.05
    # With VPoser weights (optimize(pose_prior=...)), body joints 1..21 are optimised as VPoser latents
    # (SLAHMR's pose variables, initialised by encoding the initial pose; the hand joints stay fixed); False keeps
    # axis-angle poses under the VPoser prior on their encoding.
    latent_pose: bool = True
    num_threads: int = 2
    # "m3c": Ceres's Levenberg-Marquardt iteration with M3C's assembly of the normal equations (the same steps and
    # costs, faster); "ceres": ceres::Solve itself, the reference (a stage with a bounded parameter takes it).
    minimizer: str = "m3c"
    stages: list[StageSpec] = field(default_factory=list)

    @classmethod
    def default(cls) -> "OptimizerConfig":
        core = _core.default_optimizer_config()
        stages = [StageSpec(s.name, [g for g in PARAMETER_GROUPS if getattr(s, g)], dict(s.weights), s.max_iterations)
                  for s in core.stages]
        scalars = {f.name: getattr(core, f.name) for f in fields(cls) if f.name not in ("world_check", "stages")}
        return cls(**scalars, world_check=dict(core.world_check), stages=stages)

    def validate(self) -> None:
        """Raises ValueError naming the first bad setting (the C++ core would refuse it later, or worse, Ceres
        would abort the process on num_threads < 1)."""
        if isinstance(self.num_threads, bool) or not isinstance(self.num_threads, Integral) or self.num_threads < 1:
            raise ValueError(f"num_threads must be an integer >= 1, got {self.num_threads!r}")
        if self.minimizer not in MINIMIZERS:
            raise ValueError(f"minimizer must be one of {MINIMIZERS}, got {self.minimizer!r}")
        if isinstance(self.well_seen_keypoints, bool) or not isinstance(self.well_seen_keypoints, Integral) \
                or self.well_seen_keypoints < 1:
            raise ValueError(f"well_seen_keypoints must be an integer >= 1, got {self.well_seen_keypoints!r}")
        for key in ("robust_sigma", "min_depth", "upright_sigma"):
            value = getattr(self, key)
            if not (isinstance(value, Real) and math.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be a finite number > 0, got {value!r}")
        for key in ("min_confidence", "contact_threshold"):
            value = getattr(self, key)
            if not (isinstance(value, Real) and 0 <= value <= 1):
                raise ValueError(f"{key} must lie in [0, 1], got {value!r}")
        for key in ("contact_height_tolerance", "max_world_increase", "contact_velocity_sigma"):
            value = getattr(self, key)
            if isinstance(value, bool) or not (isinstance(value, Real) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be a finite number >= 0, got {value!r}")
        known_terms = set(_core.builtin_optimizer_terms()) | set(_core.learned_optimizer_terms())
        builtin = set(_core.builtin_optimizer_terms())
        if not isinstance(self.world_check, dict):
            raise ValueError(f"world_check must map term names to weights, got {self.world_check!r}")
        for term, weight in self.world_check.items():
            if term not in builtin:
                raise ValueError(f"world_check: unknown term {term!r}; choose from {sorted(builtin)}")
            if isinstance(weight, bool) or not isinstance(weight, Real) or not math.isfinite(weight) or weight < 0:
                raise ValueError(f"world_check: weight of {term} must be a finite number >= 0, got {weight!r}")
        for stage in self.stages:
            if isinstance(stage.max_iterations, bool) or not isinstance(stage.max_iterations, Integral) \
                    or stage.max_iterations < 0:
                raise ValueError(f"stage {stage.name!r}: max_iterations must be an integer >= 0, "
                                 f"got {stage.max_iterations!r}")
            for term, weight in stage.weights.items():
                if isinstance(weight, bool) or not isinstance(weight, Real) or not math.isfinite(weight) \
                        or weight < 0:
                    raise ValueError(f"stage {stage.name!r}: weight of {term} must be a finite number >= 0, "
                                     f"got {weight!r}")
            unknown = set(stage.free) - set(PARAMETER_GROUPS)
            if unknown:
                raise ValueError(f"stage {stage.name!r}: unknown parameter groups {sorted(unknown)}; "
                                 f"choose from {list(PARAMETER_GROUPS)}")
            bad = set(stage.weights) - known_terms
            if bad:
                raise ValueError(f"stage {stage.name!r}: unknown terms {sorted(bad)}; choose from {sorted(known_terms)}")

    def to_core(self) -> "_core.OptimizerConfig":
        self.validate()
        core = _core.OptimizerConfig()
        for f in fields(self):  # the scalar settings; the core has each under the same name
            if f.name not in ("world_check", "stages"):
                setattr(core, f.name, getattr(self, f.name))
        core.world_check = {k: float(v) for k, v in self.world_check.items()}
        stages = []
        for spec in self.stages:
            s = _core.StageConfig()
            s.name = spec.name
            for g in PARAMETER_GROUPS:
                setattr(s, g, g in spec.free)
            s.weights = {k: float(v) for k, v in spec.weights.items()}
            s.max_iterations = int(spec.max_iterations)
            stages.append(s)
        core.stages = stages
        return core

    def to_yaml(self) -> str:
        return yaml.safe_dump(asdict(self), sort_keys=False)

    @classmethod
    def from_yaml(cls, text_or_path: str | Path) -> "OptimizerConfig":
        text = Path(text_or_path).read_text() if isinstance(text_or_path, Path) else text_or_path
        raw = yaml.safe_load(text) or {}
        base = cls.default()
        unknown = set(raw) - set(asdict(base))
        if unknown:
            raise ValueError(f"unknown optimizer settings {sorted(unknown)}")
        stages = raw.pop("stages", None)
        for key, value in raw.items():
            setattr(base, key, _coerce(key, value, type(getattr(base, key))))
        if stages is not None:
            try:
                base.stages = [StageSpec(**s) for s in stages]
            except TypeError as err:
                raise ValueError(f"stages: each stage takes name, free, weights, max_iterations ({err})") from None
        base.validate()
        return base


def _coerce(key: str, value, kind: type):
    """A YAML value as the setting's type, refusing lossy conversions (0.5 -> 0 threads, "no" -> True)."""
    if kind is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{key} must be true or false, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key} must be an integer, got {value!r}")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, Real):
            raise ValueError(f"{key} must be a number, got {value!r}")
        return float(value)
    return value
