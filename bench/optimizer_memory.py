"""Peak memory of the world optimizer: one m3c.motion.optimize call (the default recipe, 2 threads) on
bench/motion_optimizer.py's scene (m3c.eval.scenes at the estimated scale), without and with the HuMoR term (random
weights of the official size, exported to safetensors by a separate process), each variant in its own process that
does not import torch.

    python bench/optimizer_memory.py [--frames 600] [--people 2] [--no-humor]

Per variant: the process's peak resident memory (VmHWM), its resident memory before the call, the peak during the
call alone (VmHWM reset at its start), the call's seconds, and each stage's cost before and after (17 digits, to
compare two builds).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from optimizer_scene import add_scene_arguments, optimizer_scene
from proc_memory import reset_peak, status_mib

EXPORT = """
import sys, torch
from m3c.models.export import export_weights
from m3c.models.humor import HumorModel
torch.manual_seed(0)
export_weights(sys.argv[1], humor=HumorModel().eval(), dtype="float64")
"""


def measure(frames: int, people: int, seed: int, humor: str | None) -> dict:
    """One optimize call in this process; its memory and stage costs."""
    import time

    from m3c.motion import OptimizerConfig, optimize

    model, scene, _, (init, cameras) = optimizer_scene(frames, people, seed)
    config = OptimizerConfig.default()
    config.num_threads = 2
    before = status_mib("VmRSS")
    process_peak = status_mib("VmHWM")
    reset_peak()
    t0 = time.perf_counter()
    res = optimize(model, init, cameras, config=config, motion_prior=humor, fps=scene.fps)
    seconds = time.perf_counter() - t0
    call_peak = status_mib("VmHWM")
    assert "torch" not in sys.modules, "the measured process imported torch"
    return {"rss_before_mb": before, "call_peak_mb": call_peak, "process_peak_mb": max(process_peak, call_peak),
            "seconds": seconds,
            "stages": [(s.name, s.status, s.iterations, s.objective_before, s.objective_after) for s in res.stages]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--no-humor", action="store_true", help="only the variant without the motion prior")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--humor", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.frames, args.people, args.seed, args.humor)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        variants = [("without the motion prior", None)]
        if not args.no_humor:
            subprocess.run([sys.executable, "-c", EXPORT, tmp], check=True)
            variants.append(("with the HuMoR term (random weights)", str(Path(tmp) / "humor.safetensors")))
        print(f"{args.people} people x {args.frames} frames, seed {args.seed}")
        for label, humor in variants:
            cmd = [sys.executable, __file__, "--child", "--frames", str(args.frames), "--people", str(args.people),
                   "--seed", str(args.seed)] + (["--humor", humor] if humor else [])
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            m = json.loads(out.strip().splitlines()[-1])
            print(f"\n{label}: process peak {m['process_peak_mb']:.0f} MiB (VmHWM), {m['rss_before_mb']:.0f} MiB "
                  f"resident before the call, peak during the call {m['call_peak_mb']:.0f} MiB; {m['seconds']:.1f} s")
            for name, status, iters, before, after in m["stages"]:
                print(f"  {name:<18}{status:<10}{iters:>4}  {before:.17g} -> {after:.17g}")


if __name__ == "__main__":
    main()
