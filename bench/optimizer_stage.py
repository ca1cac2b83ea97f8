"""One stage of the world optimizer alone, from the bench scene's state before it, run several times: its time,
iterations and costs. The stages before it run once, each as its own call, as bench/motion_optimizer.py runs them
(no torch). For profiling a stage (`perf record -g python3 bench/optimizer_stage.py`) and for trying the
optimizer's settings and weights on the same start.

    python bench/optimizer_stage.py [--stage joint_smoothness] [--repeats 3] [--max-iterations N]
        [--set contact_velocity_sigma=0] [--weight upright=0]

--set changes an OptimizerConfig field for the timed stage only (the start is the recipe's); --weight changes one of
the stage's term weights (0 leaves the term out). With changes, the recipe's stage runs too, alternating with the
changed one (these machines are noisy), and the changed one's time is printed as a ratio to the recipe's (medians).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from m3c.motion import OptimizerConfig, optimize

from optimizer_scene import add_scene_arguments, optimizer_scene, world_error_mm


def key_value(text: str) -> tuple[str, float]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, float(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--stage", default="joint_smoothness")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-iterations", type=int, default=None, help="the timed stage's cap (default: the recipe's)")
    parser.add_argument("--set", type=key_value, action="append", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--weight", type=key_value, action="append", default=[], metavar="TERM=WEIGHT")
    args = parser.parse_args()

    model, scene, estimate, (tracks, cameras) = optimizer_scene(args.frames, args.people, args.seed)
    config = OptimizerConfig.default()
    names = [s.name for s in config.stages]
    if args.stage not in names:
        parser.error(f"no stage {args.stage!r} in the recipe: {', '.join(names)}")
    fields = {f.name for f in dataclasses.fields(OptimizerConfig)} - {"stages", "world_check"}
    for key, _ in args.set:
        if key not in fields:
            parser.error(f"--set {key}: not an OptimizerConfig field ({', '.join(sorted(fields))})")
    index = names.index(args.stage)
    scale = cameras.initial_scale
    for spec in config.stages[:index]:
        res = optimize(model, tracks, dataclasses.replace(cameras, initial_scale=scale),
                       dataclasses.replace(config, stages=[spec]), fps=scene.fps)
        tracks, scale = res.tracks, res.camera_scale
    spec = config.stages[index]
    weights = dict(spec.weights)
    for term, weight in args.weight:
        if term not in weights:
            parser.error(f"--weight {term}: not a term of stage {args.stage} ({', '.join(sorted(weights))})")
        weights[term] = weight
    recipe = dataclasses.replace(spec, max_iterations=args.max_iterations if args.max_iterations is not None
                                 else spec.max_iterations)
    changed = dataclasses.replace(recipe, weights={t: w for t, w in weights.items() if w > 0})
    variants = [("recipe", dataclasses.replace(config, stages=[recipe]))]
    if args.set or args.weight:
        variants.append(("changed", dataclasses.replace(config, stages=[changed], **dict(args.set))))
    print(f"scene: {args.people} people x {args.frames} frames (seed {args.seed}); stage {recipe.name}, at most "
          f"{recipe.max_iterations} iterations, {config.num_threads} threads; changes: "
          f"{', '.join(f'{k}={v:g}' for k, v in args.set + args.weight) or 'none'}")
    seconds = {label: [] for label, _ in variants}
    for run in range(args.repeats):
        for label, timed in variants:
            res = optimize(model, tracks, dataclasses.replace(cameras, initial_scale=scale), timed, fps=scene.fps)
            report = res.stages[0]
            seconds[label].append(report.seconds)
            print(f"  run {run + 1} {label:<8} {report.status}, {report.iterations} iterations, {report.seconds:.2f} s, "
                  f"cost {report.objective_before:.6g} -> {report.objective_after:.8g}, world joint error "
                  f"{world_error_mm(model, res.tracks, scene.truth):.1f} mm", flush=True)
    if len(variants) == 2:
        print(f"  changed / recipe time (medians): {np.median(seconds['changed']) / np.median(seconds['recipe']):.3f}")

if __name__ == "__main__":
    main()
