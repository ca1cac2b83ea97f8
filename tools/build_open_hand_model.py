#!/usr/bin/env python3
"""Builds the hands of M3C's open body model (SMPL-H/MANO finger layout) from the CC0 MakeHuman hm08 assets.

    python tools/build_open_hand_model.py [ASSETS] [--out python/m3c/body/data/m3c_open_hands.npz]

ASSETS as for tools/build_open_body_model.py, whose build() it runs (same re-posing, same shape space; the
body arrays it yields must match the shipped m3c_open_body.npz). Steps:
1. Every MakeHuman finger bone (finger1-* = thumb, finger2-* = index, finger3 = middle, finger4 = ring,
   finger5 = little) is one SMPL-H finger joint: its head, re-posed to the T-pose like the body, is the joint;
   the third bones' tails are the fingertips. Mean shape and the 10 shape components, as the body's joints.
2. The vertices the body's hand joint carries get MakeHuman's own weights on the 15 finger bones (which the
   body merged into its hand joint), so they sum to the body's hand-joint weight.
3. The wrists' rest positions and shape directions come from the body's J_regressor, so the fingers hang off
   the same wrist joints the body poses.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from m3c.body.hands import (FINGERS, HAND_JOINT_NAMES, HAND_JOINTS, HAND_MODEL_NAME, SIDES,  # noqa: E402
                            TIP_JOINTS, WRIST_JOINTS)
from m3c.body.open_model import OPEN_MODEL_NAME, open_body_model_path  # noqa: E402

DEFAULT_OUT = REPO / "python" / "m3c" / "body" / "data" / "m3c_open_hands.npz"
MAKEHUMAN_FINGER = {"thumb": 1, "index": 2, "middle": 3, "ring": 4, "pinky": 5}
ORIGIN = ("Built by tools/build_open_hand_model.py from the MakeHuman hm08 assets (base.obj, default "
          "skeleton and weights, macrodetails targets) of makehumancommunity/makehuman @a8bc2d54, released "
          "under CC0 1.0 (see LICENSE.ASSETS.md next to this file). The derived hand model is also CC0 1.0.")


def load_body_builder():
    path = REPO / "tools" / "build_open_body_model.py"
    spec = importlib.util.spec_from_file_location("build_open_body_model", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def finger_bone(side: str, joint: str) -> str:
    return f"finger{MAKEHUMAN_FINGER[joint[:-1]]}-{joint[-1]}{'.L' if side == 'left' else '.R'}"


def build(assets_dir: Path, verbose: bool = True):
    """(arrays of the hand model file, the body builder's arrays, report)."""
    log = print if verbose else (lambda *a, **k: None)
    builder = load_body_builder()
    body, report = builder.build(assets_dir, verbose=verbose)
    assets, skeleton, world = report["assets"], report["skeleton"], report["world"]
    mean_w, coeffs = report["mean_target_weights"], report["component_target_weights"]
    offsets = report["target_offsets"]

    raw = json.loads((assets_dir / "rigs" / "default.mhskel").read_text())
    tail_ids = [np.asarray(raw["joints"][raw["bones"][b]["tail"]]) for b in skeleton.bones]

    def posed_points(vertices):
        """Re-posed bone heads and tails (... x bones x 3) of meshes or target offsets (... x N x 3), linear
        in them."""
        heads = skeleton.heads(vertices)
        tails = np.stack([vertices[..., ids, :].mean(axis=-2) for ids in tail_ids], axis=-2)
        _, posed_heads = builder.skinning_transforms(skeleton, world, heads)
        posed_tails = posed_heads + np.einsum("kab,...kb->...ka", world, tails - heads)
        return posed_heads, posed_tails

    base_heads, base_tails = posed_points(assets.vertices)
    target_heads, target_tails = posed_points(offsets)  # T x bones x 3
    heads = base_heads + np.einsum("t,tkc->kc", mean_w, target_heads) - report["shift"]
    tails = base_tails + np.einsum("t,tkc->kc", mean_w, target_tails) - report["shift"]
    head_dirs = np.einsum("tb,tkc->kcb", coeffs, target_heads)
    tail_dirs = np.einsum("tb,tkc->kcb", coeffs, target_tails)

    template = body["v_template"].astype(np.float64)
    shapedirs = body["shapedirs"].astype(np.float64)
    regressor = body["J_regressor"].astype(np.float64)
    bones = np.asarray([[skeleton.index[finger_bone(s, j)] for j in HAND_JOINT_NAMES] for s in SIDES])
    tip_bones = bones[:, list(TIP_JOINTS)]
    wrists = np.asarray([WRIST_JOINTS[s] for s in SIDES])
    arrays = dict(
        m3c_hand_format=np.asarray(1),
        joint_names=np.asarray(HAND_JOINT_NAMES),
        fingers=np.asarray(FINGERS),
        wrist_template=(regressor[wrists] @ template).astype(np.float32),
        wrist_shapedirs=np.einsum("jv,vcb->jcb", regressor[wrists], shapedirs).astype(np.float32),
        joints_template=heads[bones].astype(np.float32),
        joints_shapedirs=head_dirs[bones].astype(np.float32),
        tips_template=tails[tip_bones].astype(np.float32),
        tips_shapedirs=tail_dirs[tip_bones].astype(np.float32),
        model_name=np.asarray(HAND_MODEL_NAME),
        body_model=np.asarray(OPEN_MODEL_NAME),
        licence=np.asarray("CC0-1.0"),
        origin=np.asarray(ORIGIN),
    )
    body_weights = body["weights"].astype(np.float64)
    hand_report = {}
    for s, side in enumerate(SIDES):
        carried = body_weights[:, HAND_JOINTS[side]]
        ids = np.flatnonzero(carried > 0)
        w = assets.weights[ids][:, bones[s]]
        arrays[f"{side}_vertex_ids"] = ids.astype(np.int32)
        arrays[f"{side}_weights"] = w.astype(np.float32)
        weight_error = float(np.abs(w.sum(axis=1) - carried[ids]).max())
        hand_report[side] = dict(vertices=len(ids), weight_error=weight_error)
        # The skeleton's wrist head against the body's regressed wrist (mean shape).
        wrist_bone = skeleton.index["wrist" + (".L" if side == "left" else ".R")]
        hand_report[side]["wrist_gap_mm"] = float(1000 * np.linalg.norm(
            heads[wrist_bone] - arrays["wrist_template"][s]))
    log(f"hands: {hand_report}")
    return arrays, body, dict(hands=hand_report, bone_heads=heads, bone_tails=tails, skeleton=skeleton)


def main(argv=None) -> int:
    builder = load_body_builder()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("assets", nargs="?", type=Path, default=builder.DEFAULT_ASSETS,
                        help=f"MakeHuman hm08 asset folder (default {builder.DEFAULT_ASSETS})")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output .npz (default {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    arrays, body, _ = build(args.assets)
    with np.load(open_body_model_path()) as shipped:
        for key in ("v_template", "shapedirs", "J_regressor", "weights"):
            if not np.allclose(shipped[key], body[key], rtol=0, atol=2e-5):
                raise SystemExit(f"the rebuilt body's {key} differs from the shipped "
                                 f"{open_body_model_path()}: rebuild the body first "
                                 "(tools/build_open_body_model.py)")
    builder.write_npz(args.out, arrays)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
