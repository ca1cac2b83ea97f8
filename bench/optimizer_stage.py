"""One stage of the world optimizer alone, from the bench scene's state before it, run several times: its time,
iterations and costs. The stages before it run once, each as its own call, as bench/motion_optimizer.py runs them
(no torch). For profiling a stage (`perf record -g python3 bench/optimizer_stage.py`) and for trying the
optimizer's settings and weights on the same start.

    python bench/optimizer_stage.py [--stage joint_smoothness] [--repeats 3] [--max-iterations N]
        [--set contact_velocity_sigma=0] [--weight upright=0]

--set changes an optimizer setting for the timed stage only (the start is the recipe's), read as the optimizer's
YAML settings are (OptimizerConfig.from_yaml: typed and validated); --weight changes one of the stage's term weights
(0 leaves the term out). With changes, the recipe's stage runs too, alternating with the
changed one (these machines are noisy), and the changed one's time is printed as a ratio to the recipe's (medians).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import yaml

from m3c.motion import OptimizerConfig, optimize

from optimizer_scene import add_scene_arguments, optimizer_scene, world_error_mm


def key_value(text: str) -> tuple[str, object]:
    """KEY=VALUE, the value read as YAML (2 an integer, 0.5 a number, true a boolean; also 1e6, which YAML 1.1
    leaves a string)."""
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    parsed = yaml.safe_load(value)
    if isinstance(parsed, str):
        try:
            parsed = float(parsed)
        except ValueError:
            pass
    return key, parsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--stage", default="joint_smoothness")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-iterations", type=int, default=None,
                        help="the timed stage's cap (default: the recipe's)")
    parser.add_argument("--set", type=key_value, action="append", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--weight", type=key_value, action="append", default=[], metavar="TERM=WEIGHT")
    args = parser.parse_args()

    model, scene, estimate, (tracks, cameras) = optimizer_scene(args.frames, args.people, args.seed)
    config = OptimizerConfig.default()
    names = [s.name for s in config.stages]
    if args.stage not in names:
        parser.error(f"no stage {args.stage!r} in the recipe: {', '.join(names)}")
    try:
        settings = OptimizerConfig.from_yaml(yaml.safe_dump(dict(args.set)))
    except ValueError as err:
        parser.error(f"--set: {err}")
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
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not weight >= 0:
            parser.error(f"--weight {term}: a weight is a number >= 0, got {weight!r}")
        weights[term] = float(weight)
    recipe = dataclasses.replace(spec, max_iterations=args.max_iterations if args.max_iterations is not None
                                 else spec.max_iterations)
    changed = dataclasses.replace(recipe, weights={t: w for t, w in weights.items() if w > 0})
    variants = [("recipe", dataclasses.replace(config, stages=[recipe]))]
    if args.set or args.weight:
        variants.append(("changed", dataclasses.replace(settings, stages=[changed])))
    print(f"scene: {args.people} people x {args.frames} frames (seed {args.seed}); stage {recipe.name}, at most "
          f"{recipe.max_iterations} iterations, {config.num_threads} threads; changes: "
          f"{', '.join(f'{k}={v}' for k, v in args.set + args.weight) or 'none'}")
    seconds = {label: [] for label, _ in variants}
    for run in range(args.repeats):
        for label, timed in variants:
            res = optimize(model, tracks, dataclasses.replace(cameras, initial_scale=scale), timed, fps=scene.fps)
            report = res.stages[0]
            seconds[label].append(report.seconds)
            print(f"  run {run + 1} {label:<8} {report.status}, {report.iterations} iterations, "
                  f"{report.seconds:.2f} s, cost {report.objective_before:.6g} -> {report.objective_after:.8g}, "
                  f"world joint error {world_error_mm(model, res.tracks, scene.truth):.1f} mm", flush=True)
    if len(variants) == 2:
        ratio = np.median(seconds["changed"]) / np.median(seconds["recipe"])
        print(f"  changed / recipe time (medians): {ratio:.3f}")


if __name__ == "__main__":
    main()
