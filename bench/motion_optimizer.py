"""Staged world optimizer: its Levenberg-Marquardt ("Ceres" below: Ceres's iteration, by M3C's minimizer unless
--minimizer ceres) per stage against SLAHMR's way (torch L-BFGS, lr 1, max_iter 20, strong Wolfe, on
the CPU) on the same objective, on a synthetic multi-person scene (m3c.eval.scenes), with and without the HuMoR
motion-prior term (random weights of the official size, exported to safetensors: the timing is what a real
checkpoint costs, the motion it prefers is not).

The scene's lift (camera-local bodies placed with the odometry at scale 1) first goes through M3C's scale estimator
(m3c.motion.scale, planted feet), as the pipeline's scale node does; the optimizer starts there, with the
estimate's uncertainty as its scale prior. Each stage runs as its own optimizer call from the previous stage's
Ceres result; torch starts from the same state and runs until an evaluated state
reaches the Ceres stage's final cost, or a time limit. The objective is m3c.testing.torch_objective, which the
tests check equals the C++ one. Stages before the first motion-prior stage are shared by both variants and run once.
A stage the optimizer skips in the pipeline (the same objective as the stage before it, when its learned terms
have no weights) is skipped here too. Both sides use 2 threads.

    python bench/motion_optimizer.py [--frames 600] [--people 2] [--no-humor] [--no-torch]
    python bench/motion_optimizer.py --torch-limit-max 300     # the README's run (~10 min on 2 cores)
    python bench/motion_optimizer.py --frames 20 --max-iterations 3 --humor-iterations 2 \
        --torch-limit-max 2 --torch-limit-min 1                 # quick: ~1 min

torch's time limit is checked between L-BFGS steps (each up to 20 iterations), so a run can exceed it by a step.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import torch

from m3c.motion import OptimizerConfig, StageSpec, optimize
from m3c.testing.torch_objective import StageObjective, TorchState, run_lbfgs
from optimizer_scene import add_scene_arguments, optimizer_scene, world_error_mm


def full_run(model, scene, label, **kwargs) -> None:
    """The staged optimizer in one call, as the pipeline runs it."""
    t0 = time.perf_counter()
    res = optimize(model, scene.init, scene.cameras_vo, fps=scene.fps, **kwargs)  # scene: at the estimated scale
    total = time.perf_counter() - t0
    print(f"\n{label}: {total:.1f} s total, camera scale {res.camera_scale:.3f} (true {scene.vo_scale}), "
          f"world joint error {world_error_mm(model, res.tracks, scene.truth):.0f} mm "
          f"(initial {world_error_mm(model, scene.init, scene.truth):.0f} mm)")
    print(f"  {'stage':<18}{'status':<10}{'iters':>6}{'seconds':>9}{'objective before -> after':>30}")
    for s in res.stages:
        print(f"  {s.name:<18}{s.status:<10}{s.iterations:>6}{s.seconds:>9.1f}"
              f"{s.objective_before:>15.3g} -> {s.objective_after:<12.3g}")


@dataclasses.dataclass
class Point:
    """A state of the chain: tracks and camera scale."""

    tracks: list
    scale: float


class Chain:
    """Runs stages one call at a time, Ceres then torch from the same start, and prints one row per stage."""

    def __init__(self, model, scene, config, humor_path, humor_net, args):
        self.model, self.scene, self.config, self.args = model, scene, config, args
        self.humor_path, self.humor_net = humor_path, humor_net
        self.totals = {"ceres": 0.0, "torch": 0.0, "capped": False}
        self.previous = None  # the last stage that ran

    def repeats_previous(self, point: Point, spec: StageSpec) -> str | None:
        """The optimizer's message when, run over the whole recipe, it skips this stage as a repeat of the one
        before it (the same objective: its learned terms unavailable), else None. The optimizer decides: the
        two stages are given to it at 0 iterations."""
        if self.previous is None:
            return None
        pair = [dataclasses.replace(s, max_iterations=0) for s in (self.previous, spec)]
        prior = self.humor_path if any(s.weights.get("motion_prior", 0) > 0 for s in pair) else None
        res = optimize(self.model, point.tracks, self.cameras(point.scale),
                       dataclasses.replace(self.config, stages=pair), motion_prior=prior, fps=self.scene.fps)
        second = res.stages[1]
        return second.message if second.status == "skipped" and "same objective" in second.message else None

    def cameras(self, scale):
        return dataclasses.replace(self.scene.cameras_vo, initial_scale=scale)

    def call(self, point: Point, spec: StageSpec, iterations: int):
        config = dataclasses.replace(self.config, stages=[dataclasses.replace(spec, max_iterations=iterations)])
        prior = self.humor_path if spec.weights.get("motion_prior", 0) > 0 else None
        res = optimize(self.model, point.tracks, self.cameras(point.scale), config, motion_prior=prior,
                       fps=self.scene.fps)
        return res, config

    def stage(self, point: Point, spec: StageSpec) -> Point:
        args = self.args
        repeat = self.repeats_previous(point, spec)
        if repeat is not None:  # the pipeline does not run it: neither is it timed
            print(f"  {spec.name:<18}{'skipped':<9}  ({repeat})", flush=True)
            return point
        self.previous = spec
        res, config = self.call(point, spec, spec.max_iterations)
        report = res.stages[0]
        after = Point(res.tracks, res.camera_scale)
        self.totals["ceres"] += report.seconds
        ceres_err = world_error_mm(self.model, res.tracks, self.scene.truth)
        row = (f"  {spec.name:<18}{report.status:<9}{report.iterations:>5}{report.seconds:>9.2f}"
               f"{report.objective_before:>11.4g}{report.objective_after:>11.4g}{ceres_err:>7.0f}"
               f"{res.camera_scale:>7.3f}")
        if args.no_torch or report.status != "ok":
            print(row + ("" if report.status == "ok" else f"  ({report.message})"), flush=True)
            return after
        try:
            objective = StageObjective(self.model, point.tracks, self.cameras(point.scale), config, config.stages[0],
                                       motion_prior=self.humor_net, fps=self.scene.fps)
        except ValueError as err:  # a term without a torch counterpart
            print(row + f"  torch: {err}", flush=True)
            return after
        start = TorchState.from_tracks(point.tracks, point.scale)
        warm = start.detached()  # one untimed evaluation with gradients: torch's lazy initialisation
        for g in objective.free:
            getattr(warm, g).requires_grad_(True)
        value = objective(warm)
        value.backward()
        start_value = float(value.detach())
        mismatch = abs(start_value - report.objective_before) / max(abs(report.objective_before), 1e-300)
        limit = min(max(args.torch_limit_factor * report.seconds, args.torch_limit_min), args.torch_limit_max)
        run = run_lbfgs(objective, start, target=report.objective_after, time_limit=limit)
        torch_tracks = run.state.to_tracks(point.tracks)
        torch_err = world_error_mm(self.model, torch_tracks, self.scene.truth)
        if run.seconds_to_target is not None:
            self.totals["torch"] += run.seconds_to_target
            reached = f"{run.seconds_to_target:>9.2f}"
            ratio = f"{run.seconds_to_target / max(report.seconds, 1e-9):>8.1f}"
        else:
            self.totals["torch"] += run.seconds
            self.totals["capped"] = True
            reached = f"{'>' + format(run.seconds, '.1f'):>9}"
            ratio = f"{'>' + format(run.seconds / max(report.seconds, 1e-9), '.1f'):>8}"
        print(row + f"{run.steps:>6}{run.evaluations:>6}{reached}{run.final:>11.4g}{torch_err:>7.0f}"
              f"{float(run.state.scale):>7.3f}{ratio}   {mismatch:.0e}", flush=True)
        return after

    def header(self, label):
        print(f"\n{label}")
        solver = ("M3C's LM (Ceres's iteration, CHOLMOD)" if self.config.minimizer == "m3c"
                  else "Ceres (LM, sparse normal Cholesky)")
        print(f"  {'':<18}{'--- ' + solver:<66}"
              f"{'--- torch L-BFGS (lr 1, max_iter 20, strong Wolfe)'}")
        print(f"  {'stage':<18}{'status':<9}{'iters':>5}{'seconds':>9}{'cost start':>11}{'cost end':>11}"
              f"{'W-MPJPE':>7}{'scale':>7}{'steps':>6}{'evals':>6}{'s->cost':>9}{'cost end':>11}{'W-MPJPE':>7}"
              f"{'scale':>7}{'ratio':>8}   start-cost mismatch")

    def summary(self, label, point: Point):
        t = self.totals
        ratio = t["torch"] / max(t["ceres"], 1e-9)
        torch_part = ("torch not run (--no-torch)" if self.args.no_torch else
                      f"torch {'>' if t['capped'] else ''}{t['torch']:.1f} s to the same costs (ratio "
                      f"{'>' if t['capped'] else ''}{ratio:.1f})")
        print(f"  {label}: Ceres {t['ceres']:.1f} s over the stages, {torch_part}; final camera "
              f"scale {point.scale:.3f} (true {self.scene.vo_scale}, error "
              f"{100 * abs(point.scale / self.scene.vo_scale - 1):.1f}%), world joint error "
              f"{world_error_mm(self.model, point.tracks, self.scene.truth):.0f} mm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--no-humor", action="store_true", help="only the variant without the motion prior")
    parser.add_argument("--no-torch", action="store_true", help="Ceres stages only")
    parser.add_argument("--minimizer", choices=("m3c", "ceres"), default="m3c",
                        help="the optimizer's minimizer (OptimizerConfig.minimizer): M3C's Levenberg-Marquardt, "
                             "Ceres's iteration with M3C's normal equations (default), or ceres::Solve")
    parser.add_argument("--full-run", action="store_true",
                        help="also time the staged optimizer in one call (as the pipeline runs it)")
    parser.add_argument("--max-iterations", type=int, default=None, help="cap every stage's Ceres iterations")
    parser.add_argument("--humor-iterations", type=int, default=None,
                        help="cap the Ceres iterations of stages with the motion prior (HuMoR variant only)")
    parser.add_argument("--torch-limit-factor", type=float, default=10.0,
                        help="torch time limit per stage, as a multiple of the Ceres stage's time")
    parser.add_argument("--torch-limit-min", type=float, default=5.0, help="seconds")
    parser.add_argument("--torch-limit-max", type=float, default=300.0, help="seconds")
    args = parser.parse_args()
    torch.set_num_threads(2)
    config = OptimizerConfig.default()
    config.num_threads = 2
    config.minimizer = args.minimizer
    if args.max_iterations is not None:
        for spec in config.stages:
            spec.max_iterations = min(spec.max_iterations, args.max_iterations)
    model, scene, estimate, (init, cameras_vo) = optimizer_scene(args.frames, args.people, args.seed)
    print(f"scale estimate (planted feet): {estimate.value:.3f} +- {100 * (estimate.sigma or 0):.1f}% "
          f"(true {scene.vo_scale}); the lift at scale 1: world joint error "
          f"{world_error_mm(model, scene.init, scene.truth):.0f} mm")
    scene = dataclasses.replace(scene, init=init, cameras_vo=cameras_vo)
    print(f"scene: {args.people} people x {args.frames} frames at {scene.fps:.0f} fps, body V={model.num_vertices}, "
          f"initial world joint error {world_error_mm(model, scene.init, scene.truth):.0f} mm, true camera scale "
          f"{scene.vo_scale}; Ceres and torch {torch.get_num_threads()} threads; torch limit per stage "
          f"min(max({args.torch_limit_factor:g} x Ceres, {args.torch_limit_min:g} s), {args.torch_limit_max:g} s)")

    with tempfile.TemporaryDirectory() as tmp:
        humor_path = humor_net = None
        if not args.no_humor:
            from m3c.models.export import export_weights
            from m3c.models.humor import HumorModel

            torch.manual_seed(0)
            humor_net = HumorModel().eval()
            export_weights(tmp, humor=humor_net, dtype="float64")
            humor_net = humor_net.double()
            humor_path = Path(tmp) / "humor.safetensors"

        if args.full_run:
            full_run(model, scene, "one call, without the motion prior", config=config)
            if humor_path is not None:
                full_run(model, scene, "one call, with the HuMoR term", config=config, motion_prior=humor_path)

        first_prior = next((i for i, s in enumerate(config.stages) if s.weights.get("motion_prior", 0) > 0),
                           len(config.stages))
        without = Chain(model, scene, config, None, None, args)
        without.header("stages before the motion prior (the same with and without it)")
        point = Point(scene.init, scene.cameras_vo.initial_scale)
        for spec in config.stages[:first_prior]:
            point = without.stage(point, spec)
        shared = dict(without.totals)

        variants = [("without the motion prior", None, None)]
        if humor_path is not None:
            variants.append(("with the HuMoR term (random weights)", humor_path, humor_net))
        for label, path, net in variants:
            variant = config
            if path is not None and args.humor_iterations is not None:
                variant = dataclasses.replace(config, stages=[
                    dataclasses.replace(s, max_iterations=min(s.max_iterations, args.humor_iterations))
                    if s.weights.get("motion_prior", 0) > 0 else s for s in config.stages])
                label += f", motion-prior stages capped at {args.humor_iterations} iterations"
            chain = Chain(model, scene, variant, path, net, args)
            chain.totals, chain.previous = dict(shared), without.previous
            chain.header(f"{label}: the remaining stages")
            end = point
            for spec in variant.stages[first_prior:]:
                end = chain.stage(end, spec)
            chain.summary(f"all stages {label}", end)


if __name__ == "__main__":
    main()
