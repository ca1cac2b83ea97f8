"""Staged world optimizer: time per stage on a synthetic multi-person scene (m3c.eval.scenes), with and without
the HuMoR motion-prior term (random weights of the official size, exported to safetensors: the timing is what a
real checkpoint costs, the motion it prefers is not).

    python bench/motion_optimizer.py [--frames 600] [--people 2] [--no-humor]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from m3c.body import BodyModel
from m3c.body.synthetic import make_synthetic_model
from m3c.eval.scenes import make_scene
from m3c.motion import optimize, track_joints


def world_error_mm(model, tracks, truth) -> float:
    return 1000 * float(np.mean([np.linalg.norm(track_joints(model, a) - track_joints(model, b), axis=-1).mean()
                                 for a, b in zip(tracks, truth)]))


def run(model, scene, label, **kwargs) -> None:
    t0 = time.perf_counter()
    res = optimize(model, scene.init, scene.cameras_vo, fps=scene.fps, **kwargs)
    total = time.perf_counter() - t0
    print(f"\n{label}: {total:.1f} s total, camera scale {res.camera_scale:.3f} (true {scene.vo_scale}), "
          f"world joint error {world_error_mm(model, res.tracks, scene.truth):.0f} mm "
          f"(initial {world_error_mm(model, scene.init, scene.truth):.0f} mm)")
    print(f"  {'stage':<18}{'status':<10}{'iters':>6}{'seconds':>9}{'objective before -> after':>30}")
    for s in res.stages:
        print(f"  {s.name:<18}{s.status:<10}{s.iterations:>6}{s.seconds:>9.1f}"
              f"{s.objective_before:>15.3g} -> {s.objective_after:<12.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--people", type=int, default=2)
    parser.add_argument("--no-humor", action="store_true")
    args = parser.parse_args()
    model = BodyModel(make_synthetic_model())
    scene = make_scene(model, num_people=args.people, num_frames=args.frames, seed=3)
    print(f"scene: {args.people} people x {args.frames} frames at {scene.fps:.0f} fps, body V={model.num_vertices}")
    run(model, scene, "without the motion prior")
    if args.no_humor:
        return
    import torch

    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel

    torch.manual_seed(0)
    with tempfile.TemporaryDirectory() as tmp:
        export_weights(tmp, humor=HumorModel().eval(), dtype="float64")
        run(model, scene, "with the HuMoR term (random weights)", motion_prior=Path(tmp) / "humor.safetensors")


if __name__ == "__main__":
    main()
