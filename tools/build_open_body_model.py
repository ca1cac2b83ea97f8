#!/usr/bin/env python3
"""Builds M3C's open body model (SMPL layout) from the CC0 MakeHuman hm08 assets.

    python tools/build_open_body_model.py [ASSETS] [--out python/m3c/body/data/m3c_open_body.npz]

ASSETS is a folder holding base.obj, rigs/default.mhskel, rigs/default_weights.mhw, targets/macrodetails/**
and modifiers/ (default: ../shared/data/body_model/makehuman relative to the repository). No MakeHuman code is
used; the macro-modifier weighting below is written from MakeHuman's documented behaviour (modifier
descriptions in modifiers/modeling_modifiers_desc.json and the target file naming).

Steps:
1. Read the hm08 base mesh (decimetres) and the default skeleton; every bone head is the mean of a vertex group.
2. Re-pose the mesh from MakeHuman's A-pose (arms 50 degrees down, elbows bent, legs apart) to SMPL's T-pose with
   linear blend skinning on MakeHuman's own weights. The bone rotations are fixed (computed once on the mean
   shape), so the re-posing is a linear map of vertex positions and applies to every shape target alike.
3. Sample macro settings (gender, age, muscle, weight, height, proportions, ethnic mix) of adults, turn them into
   target weights, and take the principal components of the re-posed shapes: v_template is the mean shape, the
   10 shape components are ordered by variance and scaled to one standard deviation (beta ~ N(0, 1)).
4. Map MakeHuman's bones onto SMPL's 24 joints (skinning weights of a bone without SMPL counterpart go to its
   nearest mapped ancestor) and fit a sparse, non-negative J_regressor (rows sum to 1) on body vertices that
   reproduces the skeleton's joint positions for the mean shape and along every shape component.
5. Pick keypoint vertices (nose, eyes, ears, toes, heels, hands), keep body vertices only, triangulate.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from m3c.body.joint_names import KEYPOINT_VERTEX_NAMES, SMPL_JOINT_NAMES, SMPL_PARENTS  # noqa: E402
from m3c.body.model_file import M3C_FORMAT_VERSION  # noqa: E402

ASSETS_IN_SHARED = Path("shared", "data", "body_model", "makehuman")


def default_assets() -> Path:
    """../shared/data/body_model/makehuman next to the repository (or next to a parent, for git worktrees)."""
    for folder in REPO.parents:
        if (folder / ASSETS_IN_SHARED).is_dir():
            return folder / ASSETS_IN_SHARED
    return REPO.parent / ASSETS_IN_SHARED


DEFAULT_ASSETS = default_assets()
DEFAULT_OUT = REPO / "python" / "m3c" / "body" / "data" / "m3c_open_body.npz"
MODEL_NAME = "m3c-open-hm08"
ORIGIN = ("Built by tools/build_open_body_model.py from the MakeHuman hm08 assets (base.obj, default skeleton and "
          "weights, macrodetails targets) of makehumancommunity/makehuman @a8bc2d54, released under CC0 1.0 "
          "(see LICENSE.ASSETS.md next to this file). The derived model is also CC0 1.0.")
DECIMETRE = 0.1  # MakeHuman meshes are in decimetres
NUM_BETAS = 10

# SMPL joint -> MakeHuman bone(s) whose head defines the joint. Several bones: the joint is the mean of their heads.
JOINT_BONES = {
    "pelvis": ["spine05"], "spine1": ["spine03"], "spine2": ["spine02"], "spine3": ["spine01"],
    "neck": ["neck01"], "head": ["head"],
    "left_hip": ["upperleg01.L"], "left_knee": ["lowerleg01.L"], "left_ankle": ["foot.L"],
    "left_foot": [f"toe{i}-1.L" for i in range(1, 6)],
    # SMPL's collar pivots halfway along the collarbone (about 8 cm from the midline), not at the sternum.
    "left_collar": ["clavicle.L", "shoulder01.L"], "left_shoulder": ["upperarm01.L"], "left_elbow": ["lowerarm01.L"],
    "left_wrist": ["wrist.L"], "left_hand": [f"finger{i}-1.L" for i in range(2, 6)],
}
for _name in list(JOINT_BONES):
    if _name.startswith("left_"):
        JOINT_BONES["right_" + _name[5:]] = [b[:-2] + ".R" for b in JOINT_BONES[_name]]
# Bones whose skinning weights start a new SMPL joint; every other bone inherits its nearest listed ancestor's.
SKINNING_ROOTS = {"root": "pelvis", "spine03": "spine1", "spine02": "spine2", "spine01": "spine3", "neck01": "neck",
                  "head": "head"}
for _side, _prefix in ((".L", "left_"), (".R", "right_")):
    SKINNING_ROOTS.update({
        "upperleg01" + _side: _prefix + "hip", "lowerleg01" + _side: _prefix + "knee",
        "foot" + _side: _prefix + "ankle", "clavicle" + _side: _prefix + "collar",
        "upperarm01" + _side: _prefix + "shoulder", "lowerarm01" + _side: _prefix + "elbow",
        "wrist" + _side: _prefix + "wrist",
        **{f"toe{i}-1{_side}": _prefix + "foot" for i in range(1, 6)},
        **{f"finger{i}-1{_side}": _prefix + "hand" for i in range(1, 6)},  # the thumb too, as in SMPL
    })

# Leg directions of SMPL's rest pose in the frontal plane (degrees from straight down, positive = outward):
# thighs open slightly and shins come back in, as in SMPL (MakeHuman stands with its feet apart).
THIGH_OUTWARD_DEG = 6.0
SHIN_OUTWARD_DEG = -2.5


# ---------------------------------------------------------------------------------------------------------------
# Reading the assets
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class Assets:
    vertices: np.ndarray  # all 19158 vertices (metres), helpers included
    body_vertex_ids: np.ndarray  # vertices of the 'body' group
    body_quads: np.ndarray  # Q x 4, original vertex ids
    group_vertex_ids: dict  # obj group -> vertex ids
    bones: list  # topological order
    bone_parent: dict
    bone_head_ids: dict  # bone -> vertex ids whose mean is the head
    weights: np.ndarray  # V_body x num_bones, rows sum to 1
    targets: dict  # path below targets/macrodetails -> dense N x 3 offsets in metres


def read_obj(path: Path):
    vertices, faces, group = [], {}, None
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("g "):
                group = line.split()[1]
            elif line.startswith("f "):
                faces.setdefault(group, []).append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
    return np.asarray(vertices) * DECIMETRE, faces


def read_target(path: Path, num_vertices: int) -> np.ndarray:
    """A .target(.gz) file: lines 'index dx dy dz' after '#' comments -> dense N x 3 offsets in metres."""
    text = gzip.decompress(path.read_bytes()).decode("utf-8")
    text = re.sub(r"(?m)^#.*$", "", text)
    table = np.asarray(text.split(), dtype=np.float64).reshape(-1, 4)
    offsets = np.zeros((num_vertices, 3))
    offsets[table[:, 0].astype(int)] = table[:, 1:] * DECIMETRE
    return offsets


def read_assets(root: Path) -> Assets:
    needed = [root / "base.obj", root / "rigs" / "default.mhskel", root / "rigs" / "default_weights.mhw",
              root / "targets" / "macrodetails", root / "modifiers" / "modeling_modifiers.json"]
    missing = [str(p) for p in needed if not p.exists()]
    if missing:
        raise SystemExit(f"MakeHuman assets not found: {missing}. Pass the folder holding base.obj, rigs/, "
                         "targets/ and modifiers/ (the hm08 assets of makehumancommunity/makehuman, see data/SOURCES.md).")
    vertices, faces = read_obj(root / "base.obj")
    quads = np.asarray(faces["body"])
    if quads.shape[1] != 4:
        raise SystemExit("base.obj: expected quads in the 'body' group")
    body_ids = np.unique(quads)
    group_ids = {g: np.unique(np.asarray([i for f in fs for i in f])) for g, fs in faces.items()}

    skeleton = json.loads((root / "rigs" / "default.mhskel").read_text())
    parent = {name: bone["parent"] for name, bone in skeleton["bones"].items()}
    order, seen = [], set()

    def visit(name):
        if name in seen:
            return
        if parent[name] is not None:
            visit(parent[name])
        seen.add(name)
        order.append(name)

    for name in sorted(parent):
        visit(name)
    head_ids = {name: np.asarray(skeleton["joints"][skeleton["bones"][name]["head"]]) for name in order}

    raw_weights = json.loads((root / "rigs" / "default_weights.mhw").read_text())["weights"]
    index = {name: k for k, name in enumerate(order)}
    V = len(vertices)
    dense = np.zeros((V, len(order)))
    for bone, pairs in raw_weights.items():
        pairs = np.asarray(pairs)
        dense[pairs[:, 0].astype(int), index[bone]] = pairs[:, 1]
    dense = dense[body_ids]
    dense /= dense.sum(axis=1, keepdims=True)  # the file's rows sum to 0.95-1.06

    check_macro_modifiers(root / "modifiers" / "modeling_modifiers.json")
    targets = {}
    for path in sorted((root / "targets" / "macrodetails").rglob("*.target.gz")):
        rel = path.relative_to(root / "targets" / "macrodetails").as_posix()
        targets[rel] = read_target(path, V)
    return Assets(vertices, body_ids, quads, group_ids, order, parent, head_ids, dense, targets)


# ---------------------------------------------------------------------------------------------------------------
# Macro modifiers: slider values -> target weights
# ---------------------------------------------------------------------------------------------------------------
MACRO_VARIABLES = {"Gender", "Age", "African", "Asian", "Caucasian", "Muscle", "Weight", "Height", "BodyProportions"}


def check_macro_modifiers(path: Path) -> None:
    """The macro modifiers MakeHuman defines must be exactly the variables macro_factors models."""
    groups = json.loads(path.read_text())
    found = {m["macrovar"] for g in groups if g["group"].startswith("macrodetails") for m in g["modifiers"]}
    if found != MACRO_VARIABLES:
        raise SystemExit(f"{path}: macro modifiers {sorted(found)} differ from the ones this builder models "
                         f"{sorted(MACRO_VARIABLES)}")


def macro_factors(gender, age, muscle, weight, height, proportions, ethnic) -> dict:
    """Per-factor weights of macro settings (arrays of sliders in [0, 1], 0.5 = average; ethnic N x 3 sums to 1).

    Age: 0 = 1 year, 0.1875 = 10, 0.5 = 25, 1 = 90 years; baby/child/young/old blend piecewise linearly
    between those anchors. Muscle, weight, height, proportions: 0.5 is the unmodified average, the min/max
    (uncommon/ideal) target weight grows linearly to 1 at either end.
    """
    gender, age = np.asarray(gender, dtype=float), np.asarray(age, dtype=float)
    f = {"female": 1.0 - gender, "male": gender, "universal": np.ones_like(gender)}
    young_side = age < 0.5
    f["baby"] = np.where(young_side, np.maximum(0.0, 1.0 - age / 0.1875), 0.0)
    f["young"] = np.where(young_side, np.maximum(0.0, (age - 0.1875) / (0.5 - 0.1875)), 2.0 - 2.0 * age)
    f["child"] = np.where(young_side, np.maximum(0.0, np.minimum(1.0, age / 0.1875) - f["young"]), 0.0)
    f["old"] = np.where(young_side, 0.0, 2.0 * age - 1.0)
    for name, value in (("muscle", muscle), ("weight", weight), ("height", height)):
        value = np.asarray(value, dtype=float)
        f["max" + name] = np.maximum(0.0, 2.0 * value - 1.0)
        f["min" + name] = np.maximum(0.0, 1.0 - 2.0 * value)
        f["average" + name] = 1.0 - f["max" + name] - f["min" + name]
    proportions = np.asarray(proportions, dtype=float)
    f["idealproportions"] = np.maximum(0.0, 2.0 * proportions - 1.0)
    f["uncommonproportions"] = np.maximum(0.0, 1.0 - 2.0 * proportions)
    ethnic = np.asarray(ethnic, dtype=float)
    f["african"], f["asian"], f["caucasian"] = ethnic[..., 0], ethnic[..., 1], ethnic[..., 2]
    return f


def target_weights(target: str, factors: dict) -> np.ndarray:
    """A macro target's weight is the product of the factors named in its file name."""
    weight = 1.0
    for token in Path(target).name.removesuffix(".target.gz").split("-"):
        if token not in factors:
            raise SystemExit(f"macro target {target}: unknown factor '{token}'")
        weight = weight * factors[token]
    return weight


def years_to_age(years):
    return np.where(years < 25.0, (years - 1.0) / 48.0, 0.5 + (years - 25.0) / 130.0)


# Stature calibration. MakeHuman's height slider is steep and asymmetric: from 0.5 to 1 it adds about 0.72 m,
# from 0.5 to 0 it removes about 0.37 m (measured on the young male and female). Sampling the slider uniformly
# would give 1.2-2.4 m people; instead the stature change is drawn in metres and mapped back to the slider.
HEIGHT_PER_SLIDER_UP = 1.445  # metres per unit of slider above 0.5
HEIGHT_PER_SLIDER_DOWN = 0.733  # below 0.5
STATURE_SHIFT = 0.035  # MakeHuman's young adults (1.59 m female, 1.73 m male) are a little short for CAESAR
STATURE_STD = 0.06  # within-sex spread on top of the ethnic mix (which alone varies stature by a few cm)


def sample_settings(n: int, seed: int = 0) -> dict:
    """Adults of both sexes, 25-70 years: the population SMPL's shape space was learned on (CAESAR).

    Ages below 25 blend in MakeHuman's child targets (an 18-year-old gets 47% of a 10-year-old's body), so they
    are left out.
    """
    rng = np.random.default_rng(seed)
    stature = STATURE_SHIFT + STATURE_STD * rng.standard_normal(n)
    height = 0.5 + np.where(stature > 0, stature / HEIGHT_PER_SLIDER_UP, stature / HEIGHT_PER_SLIDER_DOWN)
    return dict(
        gender=rng.beta(0.5, 0.5, n),  # mostly clearly female or male, some in between
        age=years_to_age(rng.uniform(25.0, 70.0, n)),
        muscle=rng.beta(4.0, 4.0, n),
        weight=rng.beta(2.0, 2.0, n),  # 0 = about BMI 15, 1 = about BMI 35
        height=np.clip(height, 0.0, 1.0),
        proportions=rng.beta(4.0, 4.0, n),
        ethnic=rng.dirichlet(np.ones(3), n),
    )


def weight_matrix(settings: dict, target_names: list) -> np.ndarray:
    """N x T target weights of N macro settings."""
    factors = macro_factors(**settings)
    n = len(np.atleast_1d(settings["gender"]))
    return np.stack([np.broadcast_to(target_weights(t, factors), (n,)) for t in target_names], axis=1)


# ---------------------------------------------------------------------------------------------------------------
# Re-posing to SMPL's T-pose
# ---------------------------------------------------------------------------------------------------------------
def align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction a to direction b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def frame_from(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frame (columns) whose x is primary and whose xy plane holds secondary."""
    x = primary / np.linalg.norm(primary)
    z = np.cross(x, secondary)
    z /= np.linalg.norm(z)
    return np.stack([x, np.cross(z, x), z], axis=1)


class Skeleton:
    def __init__(self, assets: Assets):
        self.bones = assets.bones
        self.index = {b: k for k, b in enumerate(self.bones)}
        self.parent = [self.index[assets.bone_parent[b]] if assets.bone_parent[b] else -1 for b in self.bones]
        self.head_ids = [assets.bone_head_ids[b] for b in self.bones]

    def heads(self, vertices: np.ndarray) -> np.ndarray:
        """Bone heads (... x num_bones x 3) of meshes (... x N x 3)."""
        return np.stack([vertices[..., ids, :].mean(axis=-2) for ids in self.head_ids], axis=-2)


def tpose_rotations(skeleton: Skeleton, heads: np.ndarray) -> np.ndarray:
    """World rotations of every bone that bring the MakeHuman rest pose to SMPL's T-pose (left = +x)."""
    world = np.tile(np.eye(3), (len(skeleton.bones), 1, 1))
    ix = skeleton.index

    def direction(frm, to):
        return heads[ix[to]] - heads[ix[frm]]

    def frontal(d, degrees, sign):
        # Rotates d about z so that its angle from straight down in the frontal plane is `degrees` outward.
        current = np.degrees(np.arctan2(sign * d[0], -d[1]))
        angle = np.radians(sign * (degrees - current))
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    for bone in skeleton.bones:
        k = ix[bone]
        p = skeleton.parent[k]
        parent_world = world[p] if p >= 0 else np.eye(3)
        side = bone[-2:]
        sign = 1.0 if side == ".L" else -1.0
        if bone.startswith("upperarm01"):
            d = parent_world @ direction(bone, "lowerarm01" + side)
            world[k] = align(d, np.array([sign, 0.0, 0.0])) @ parent_world
        elif bone.startswith("lowerarm01"):
            d = parent_world @ direction(bone, "wrist" + side)
            world[k] = align(d, np.array([sign, 0.0, 0.0])) @ parent_world
        elif bone.startswith("wrist"):
            # Palm down, fingers along the arm: wrist -> knuckles along +-x, index -> little finger along -z.
            knuckles = np.mean([heads[ix[f"finger{i}-1{side}"]] for i in range(2, 6)], axis=0)
            along = knuckles - heads[k]
            across = heads[ix["finger5-1" + side]] - heads[ix["finger2-1" + side]]
            rest = frame_from(along, across)
            goal = frame_from(np.array([sign, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]))
            world[k] = goal @ rest.T
        elif bone.startswith("upperleg01"):
            d = parent_world @ direction(bone, "lowerleg01" + side)
            world[k] = frontal(d, THIGH_OUTWARD_DEG, sign) @ parent_world
        elif bone.startswith("lowerleg01"):
            d = parent_world @ direction(bone, "foot" + side)
            world[k] = frontal(d, SHIN_OUTWARD_DEG, sign) @ parent_world
        elif bone.startswith("foot"):
            world[k] = np.eye(3)  # soles stay flat on the ground
        else:
            world[k] = parent_world
    return world


def skinning_transforms(skeleton: Skeleton, world: np.ndarray, heads: np.ndarray):
    """Translations t (... x bones x 3) of the rigid bone transforms (world[b], t[b]) for fixed world rotations,
    and the posed bone heads; both are linear in the rest bone heads (... x bones x 3)."""
    t = np.zeros_like(heads)
    posed_heads = np.zeros_like(heads)
    for k, p in enumerate(skeleton.parent):
        if p < 0:
            posed_heads[..., k, :] = heads[..., k, :]
        else:
            posed_heads[..., k, :] = posed_heads[..., p, :] + (heads[..., k, :] - heads[..., p, :]) @ world[p].T
        t[..., k, :] = posed_heads[..., k, :] - heads[..., k, :] @ world[k].T
    return t, posed_heads


def repose(assets: Assets, skeleton: Skeleton, world: np.ndarray, vertices: np.ndarray):
    """Linear in `vertices` (... x N x 3: meshes, or offsets of targets): body vertices and bone heads in the
    T-pose. Each body vertex moves by the weight blend of the bone transforms (linear blend skinning)."""
    heads = skeleton.heads(vertices)
    t, posed_heads = skinning_transforms(skeleton, world, heads)
    blended_rotations = np.einsum("vb,bij->vij", assets.weights, world)
    body = vertices[..., assets.body_vertex_ids, :]
    posed = np.einsum("vij,...vj->...vi", blended_rotations, body) + assets.weights @ t
    return posed, posed_heads


# ---------------------------------------------------------------------------------------------------------------
# SMPL layout
# ---------------------------------------------------------------------------------------------------------------
def smpl_joints_from_heads(skeleton: Skeleton, heads: np.ndarray) -> np.ndarray:
    """SMPL joints (... x 24 x 3) from MakeHuman bone heads (... x bones x 3)."""
    return np.stack([np.mean([heads[..., skeleton.index[b], :] for b in JOINT_BONES[name]], axis=0)
                     for name in SMPL_JOINT_NAMES], axis=-2)


def smpl_weights(assets: Assets, skeleton: Skeleton) -> np.ndarray:
    joint_of = {}
    for bone in skeleton.bones:  # parents first
        p = skeleton.parent[skeleton.index[bone]]
        joint_of[bone] = SKINNING_ROOTS.get(bone, joint_of[skeleton.bones[p]] if p >= 0 else None)
    merge = np.zeros((len(skeleton.bones), 24))
    for bone, joint in joint_of.items():
        merge[skeleton.index[bone], SMPL_JOINT_NAMES.index(joint)] = 1.0
    # Same tree as SMPL: each mapped bone's SMPL joint hangs below the SMPL joint of its MakeHuman parent.
    for bone, joint in SKINNING_ROOTS.items():
        p = skeleton.parent[skeleton.index[bone]]
        if p >= 0 and SMPL_PARENTS[SMPL_JOINT_NAMES.index(joint)] != SMPL_JOINT_NAMES.index(joint_of[skeleton.bones[p]]):
            raise SystemExit(f"bone {bone} ({joint}) hangs below {skeleton.bones[p]} ({joint_of[skeleton.bones[p]]}), "
                             "which is not SMPL's parent joint: the skeleton is not MakeHuman's default one")
    return assets.weights @ merge


def fit_regressor(shapes: np.ndarray, joints: np.ndarray, template_joints: np.ndarray, template: np.ndarray):
    """Sparse non-negative J_regressor (rows sum to 1) over body vertices.

    shapes: S x V x 3, the mean shape first, then shape components; joints: S x 24 x 3, the skeleton's joint
    positions to reproduce (the model is linear in beta, so this covers every shape). The mean shape's rows
    are weighted 10x: it is reproduced to a fraction of a millimetre, the components as well as a convex
    combination of surface vertices can (MakeHuman moves its joint helpers a little differently from the
    surrounding skin). Candidates for joint j are the body vertices within a margin of the nearest one; deep
    joints (spine) need a margin that reaches the far side of the torso, so the margin with the smallest error
    is kept. The sum-to-one row is weighted heavily. Returns the regressor and the per-joint max error (m).
    """
    V = shapes.shape[1]
    row_weight = np.r_[10.0, np.ones(len(shapes) - 1)][:, None]
    regressor = np.zeros((24, V))
    residual = np.zeros(24)
    for j in range(24):
        dist = np.linalg.norm(template - template_joints[j], axis=1)
        best = None
        for margin in (0.03, 0.06, 0.09, 0.12):
            candidates = np.flatnonzero(dist < dist.min() + margin)
            A = shapes[:, candidates, :].transpose(0, 2, 1)  # S x 3 x C
            b = joints[:, j, :]
            Aw = (A * row_weight[:, :, None]).reshape(-1, len(candidates))
            bw = (b * row_weight).reshape(-1)
            w, _ = nnls(np.vstack([Aw, 100.0 * np.ones((1, len(candidates)))]), np.append(bw, 100.0),
                        maxiter=50 * len(candidates))
            w /= w.sum()
            err = np.abs(A @ w - b).max()
            if best is None or err < 0.9 * best[0]:
                best = (err, candidates, w)
        regressor[j, best[1]] = best[2]
        residual[j] = best[0]
    return regressor, residual


def keypoint_vertices(v: np.ndarray, weights: np.ndarray, mh_weights: np.ndarray, skeleton: Skeleton,
                      eye_fronts: dict) -> dict:
    """Named keypoint vertices on the T-posed mean shape (y up, facing +z, left = +x)."""
    J = {n: k for k, n in enumerate(SMPL_JOINT_NAMES)}
    head = weights[:, J["head"]] > 0.5
    out = {}
    near_midline = head & (np.abs(v[:, 0]) < 0.005)
    out["nose"] = int(np.flatnonzero(near_midline)[np.argmax(v[near_midline, 2])])
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # Eye: the eyelid vertex closest to the front of the (dropped) eyeball.
        front = eye_fronts[side]
        out[f"{side}_eye"] = int(np.argmin(np.linalg.norm(v - front, axis=1)))
        # Ear: centre of the outermost head vertices at eye height, snapped to the mesh.
        band = head & (np.abs(v[:, 1] - front[1] + 0.02) < 0.04) & (sign * v[:, 0] > 0)
        lateral = sign * v[:, 0]
        ear = band & (lateral > lateral[band].max() - 0.012)
        centre = v[ear].mean(axis=0)
        out[f"{side}_ear"] = int(np.argmin(np.linalg.norm(v - centre, axis=1)))
        side_tag = ".L" if side == "left" else ".R"
        for name, toe in (("big_toe", "toe1-"), ("small_toe", "toe5-")):
            cols = [skeleton.index[f"{toe}{s}{side_tag}"] for s in (1, 2, 3) if f"{toe}{s}{side_tag}" in skeleton.index]
            on_toe = mh_weights[:, cols].sum(axis=1) > 0.5
            out[f"{side}_{name}"] = int(np.flatnonzero(on_toe)[np.argmax(v[on_toe, 2])])
        foot = (weights[:, J[f"{side}_ankle"]] + weights[:, J[f"{side}_foot"]]) > 0.5
        sole = foot & (v[:, 1] < v[foot, 1].min() + 0.02)
        out[f"{side}_heel"] = int(np.flatnonzero(sole)[np.argmin(v[sole, 2])])
        middle = mh_weights[:, skeleton.index["finger3-3" + side_tag]] > 0.5
        out[f"{side}_hand"] = int(np.flatnonzero(middle)[np.argmax(sign * v[middle, 0])])
    return {name: out[name] for name in KEYPOINT_VERTEX_NAMES}


# ---------------------------------------------------------------------------------------------------------------
def build(assets_dir: Path, num_samples: int = 20000, seed: int = 0, verbose: bool = True):
    """Returns (arrays of the model file, report of fit figures)."""
    log = print if verbose else (lambda *a, **k: None)
    start = time.time()
    assets = read_assets(assets_dir)
    skeleton = Skeleton(assets)
    names = sorted(assets.targets)
    log(f"read {len(assets.vertices)} vertices, {len(assets.body_vertex_ids)} body vertices, "
        f"{len(skeleton.bones)} bones, {len(names)} macro targets ({time.time() - start:.1f} s)")

    settings = sample_settings(num_samples, seed)
    W = weight_matrix(settings, names)
    mean_w = W.mean(axis=0)
    offsets = np.stack([assets.targets[n] for n in names])  # T x N x 3
    mean_mesh = assets.vertices + np.einsum("t,tnc->nc", mean_w, offsets)
    world = tpose_rotations(skeleton, skeleton.heads(mean_mesh))

    # Re-posing is linear: re-pose the base mesh and every target once.
    base_posed, base_heads = repose(assets, skeleton, world, assets.vertices)
    posed_targets, target_heads = repose(assets, skeleton, world, offsets)  # T x V x 3, T x bones x 3
    target_joints = smpl_joints_from_heads(skeleton, target_heads)  # T x 24 x 3
    base_joints = smpl_joints_from_heads(skeleton, base_heads)

    template = base_posed + np.einsum("t,tvc->vc", mean_w, posed_targets)
    template_joints = base_joints + np.einsum("t,tjc->jc", mean_w, target_joints)

    # PCA of the sampled shapes through the target-weight covariance: cov(shapes) = D^T cov(W) D.
    cov_w = np.cov(W, rowvar=False)
    evals, evecs = np.linalg.eigh(cov_w)
    keep = evals > 1e-12 * evals.max()
    half = evecs[:, keep] * np.sqrt(evals[keep])  # T x r, half @ half.T = cov_w
    D = posed_targets.reshape(len(names), -1)
    M = half.T @ D  # r x 3V; cov(shapes) = M^T M, whose eigenvectors are M^T U for the eigenvectors U of M M^T
    gram_values, gram_vectors = np.linalg.eigh(M @ M.T)
    order = np.argsort(gram_values)[::-1]
    S = np.sqrt(np.clip(gram_values[order], 0.0, None))
    U = gram_vectors[:, order]
    coeffs = half @ U[:, :NUM_BETAS]  # T x B: shape component b = sum_t coeffs[t, b] * posed target t
    shapedirs = np.einsum("tb,tvc->vcb", coeffs, posed_targets)
    jointdirs = np.einsum("tb,tjc->jcb", coeffs, target_joints)
    explained = S[:NUM_BETAS] ** 2 / np.sum(S ** 2)

    # Signs: +beta_0 makes the body taller; the others point their largest displacement along +.
    height_dir = shapedirs[:, 1, 0]
    if height_dir[np.argmax(template[:, 1])] - height_dir[np.argmin(template[:, 1])] < 0:
        shapedirs[:, :, 0] *= -1
        jointdirs[:, :, 0] *= -1
    for b in range(1, NUM_BETAS):
        flat = shapedirs[:, :, b].reshape(-1)
        if flat[np.argmax(np.abs(flat))] < 0:
            shapedirs[:, :, b] *= -1
            jointdirs[:, :, b] *= -1
    # The components' signs against coeffs (build_open_hand_model.py follows every bone head along them).
    signs = np.sign(np.einsum("vcb,vcb->b", shapedirs, np.einsum("tb,tvc->vcb", coeffs, posed_targets)))

    weights = smpl_weights(assets, skeleton)
    shapes = np.concatenate([template[None], shapedirs.transpose(2, 0, 1)])
    joints = np.concatenate([template_joints[None], jointdirs.transpose(2, 0, 1)])
    regressor, residual = fit_regressor(shapes, joints, template_joints, template)
    regressed = np.einsum("jv,svc->sjc", regressor, shapes)
    mean_error = np.linalg.norm(regressed[0] - joints[0], axis=1).max()
    component_error = np.linalg.norm(regressed[1:] - joints[1:], axis=2).max(axis=1)

    # Pelvis at the origin for the mean shape.
    shift = regressor[0] @ template
    template = template - shift

    eyes = {}
    for side, group in (("left", "helper-l-eye"), ("right", "helper-r-eye")):
        eye_ids = assets.group_vertex_ids[group]
        # The head is not re-posed, so the mean-shape eyeball is where it was: take its front point.
        eyes[side] = mean_mesh[eye_ids][np.argmax(mean_mesh[eye_ids, 2])] - shift
    keypoints = keypoint_vertices(template, weights, assets.weights, skeleton, eyes)

    faces = assets.body_quads
    remap = -np.ones(len(assets.vertices), dtype=np.int64)
    remap[assets.body_vertex_ids] = np.arange(len(assets.body_vertex_ids))
    quads = remap[faces]
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])

    V = len(template)
    log(f"shape components explain {explained.sum():.4f} of the sampled variance; per component "
        f"{np.round(explained, 4).tolist()}; head-top rise per unit beta (m): "
        f"{np.round(shapedirs[np.argmax(template[:, 1]), 1], 4).tolist()}")
    log(f"J_regressor vs the skeleton's joints: mean shape max {1000 * mean_error:.3f} mm; per unit beta_b, "
        f"max over joints (mm): {np.round(1000 * component_error, 2).tolist()}; per joint max over all "
        f"(mm): {np.round(1000 * residual, 2).tolist()}; nonzeros per row {(regressor > 0).sum(axis=1).tolist()}")
    log(f"template height {np.ptp(template[:, 1]):.4f} m, {V} vertices, {len(triangles)} triangles, "
        f"keypoints {keypoints} ({time.time() - start:.1f} s)")
    report = dict(mean_shape_joint_error=mean_error, component_joint_error=component_error,
                  explained_variance=explained, template_height=float(np.ptp(template[:, 1])),
                  # for build_open_hand_model.py: the re-posing and the shape space, bone by bone
                  assets=assets, skeleton=skeleton, world=world, shift=shift, mean_target_weights=mean_w,
                  component_target_weights=coeffs * signs, target_names=names, target_offsets=offsets)
    # No 'posedirs': in an M3C model file (m3c_model_format) that means zero pose blend shapes.
    arrays = dict(
        m3c_model_format=np.asarray(M3C_FORMAT_VERSION),
        v_template=template.astype(np.float32),
        shapedirs=shapedirs.astype(np.float32),
        J_regressor=regressor.astype(np.float32),
        weights=weights.astype(np.float32),
        kintree_table=np.stack([np.asarray(SMPL_PARENTS), np.arange(24)]).astype(np.int64),
        f=triangles.astype(np.int32),
        keypoint_names=np.asarray(KEYPOINT_VERTEX_NAMES),
        keypoint_vertex_ids=np.asarray([keypoints[n] for n in KEYPOINT_VERTEX_NAMES], dtype=np.int32),
        joint_names=np.asarray(SMPL_JOINT_NAMES),
        model_name=np.asarray(MODEL_NAME),
        gender=np.asarray("neutral"),
        licence=np.asarray("CC0-1.0"),
        origin=np.asarray(ORIGIN),
        source_vertex_ids=assets.body_vertex_ids.astype(np.int32),
        shape_explained_variance=explained.astype(np.float32),
    )
    return arrays, report


def write_npz(path: Path, arrays: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz")
    os.close(fd)
    try:
        np.savez_compressed(tmp, **arrays)
        os.chmod(tmp, 0o644)  # mkstemp makes it private
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("assets", nargs="?", type=Path, default=DEFAULT_ASSETS,
                        help=f"MakeHuman hm08 asset folder (default {DEFAULT_ASSETS})")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output .npz (default {DEFAULT_OUT})")
    parser.add_argument("--samples", type=int, default=20000, help="macro settings sampled for the PCA")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    arrays, _ = build(args.assets, num_samples=args.samples, seed=args.seed)
    write_npz(args.out, arrays)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
