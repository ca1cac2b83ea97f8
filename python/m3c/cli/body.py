"""`m3c body info|convert`: SMPL-layout body model files."""

from __future__ import annotations

import numpy as np


def body_info(args) -> int:
    from m3c.body import BodyModel

    model = BodyModel.from_file(args.model, num_betas=None)
    data = model.data
    out = model.forward(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas))
    height = np.ptp(out.vertices[0, :, 1])
    print(f"{args.model}: {data.num_vertices} vertices, {data.num_joints} joints, {data.num_betas} shape "
          f"components, {len(data.faces)} faces, gender {data.gender}")
    print(f"rest pose: height (y extent) {height:.3f} m, weights per vertex "
          f"{(data.weights != 0).sum(1).mean():.2f}, J_regressor rows sum to "
          f"{data.J_regressor.sum(1).min():.4f}..{data.J_regressor.sum(1).max():.4f}")
    return 0


def body_convert(args) -> int:
    from m3c.body import load_model_file
    from m3c.body.layouts import to_smpl_layout
    from m3c.io import save_npz_atomic

    data = load_model_file(args.model, num_betas=None)
    if args.smpl_layout:
        data = to_smpl_layout(data)
    kintree = np.stack([data.parents, np.arange(data.num_joints)])
    save_npz_atomic(args.out, v_template=data.v_template, shapedirs=data.shapedirs, posedirs=data.posedirs,
                    J_regressor=data.J_regressor, weights=data.weights, kintree_table=kintree, f=data.faces,
                    gender=np.array(data.gender))
    print(f"wrote {args.out} ({data.num_vertices} vertices, {data.num_joints} joints), readable without chumpy")
    return 0
