"""Body-model speed: the C++ core against a torch implementation in the smplx style (batched einsum LBS, CPU)
on the same SMPL-sized model (V=6890, 24 joints, 10 betas, dense pose blend shapes, 4 skinning weights per
vertex), in the same process. Prints frames/s and the ratio at batch 1, 64 and 512, and joints-only FK frames/s.

    python bench/body_lbs.py [--repeats 7]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from m3c.body import BodyModel
from m3c.body.synthetic import make_synthetic_model, random_pose
from m3c.body.torch_lbs import TorchBodyModel


def smpl_sized_model():
    data = make_synthetic_model(num_vertices=6890, num_betas=10, seed=0)
    # SMPL's vertices are influenced by up to four joints; give every vertex four.
    rng = np.random.default_rng(1)
    weights = data.weights.copy()
    for v in range(data.num_vertices):
        extra = rng.choice(24, size=2, replace=False)
        weights[v, extra] += rng.uniform(0.05, 0.2, size=2)
    weights /= weights.sum(1, keepdims=True)
    from dataclasses import replace

    return replace(data, weights=weights)


def best_time(fn, repeats: int) -> float:
    fn()  # warm-up (lazy float copies, allocator, torch kernels)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(2)
    data = smpl_sized_model()
    model = BodyModel(data)
    tmodel = TorchBodyModel(data, dtype=torch.float32)
    nnz = (data.weights != 0).sum(1).mean()
    print(f"model: V={data.num_vertices} J={data.num_joints} B={data.num_betas}, {nnz:.1f} weights/vertex, "
          f"torch {torch.__version__} threads={torch.get_num_threads()}")
    print(f"{'batch':>6} {'C++ f32 fps':>12} {'torch f32 fps':>14} {'ratio':>7} {'C++ f64 fps':>12}")
    for batch in (1, 64, 512):
        pose = random_pose(batch, seed=batch).astype(np.float32)
        betas = np.random.default_rng(batch).normal(size=(batch, 10)).astype(np.float32)
        transl = np.zeros((batch, 3), np.float32)
        pose_t, betas_t, transl_t = map(torch.as_tensor, (pose, betas, transl))
        repeats = max(3, args.repeats if batch < 512 else args.repeats // 2)
        t_cpp = best_time(lambda: model.forward(pose, betas, transl), repeats)
        t_cpp64 = best_time(lambda: model.forward(pose.astype(np.float64), betas.astype(np.float64), transl), repeats)

        def run_torch():
            with torch.no_grad():
                tmodel(pose_t, betas_t, transl_t)

        t_torch = best_time(run_torch, repeats)
        print(f"{batch:>6} {batch / t_cpp:>12.0f} {batch / t_torch:>14.0f} {t_torch / t_cpp:>6.1f}x "
              f"{batch / t_cpp64:>12.0f}")

    n = 100_000
    pose = random_pose(n, seed=7)
    betas = np.random.default_rng(7).normal(size=10)
    t_fk = best_time(lambda: model.joints(pose, betas), 3)
    t_full = best_time(lambda: model.forward(pose[:512], betas), 3) / 512
    print(f"joints-only FK (float64, batch {n}): {n / t_fk:,.0f} frames/s "
          f"({t_full * n / t_fk:.0f}x the per-frame cost of full skinning)")


if __name__ == "__main__":
    main()
