"""HuMoR motion-prior term and its gradient: C++ runtime (cpp/nn) vs torch autograd, on the CPU, in one process.

Times the transition term NLL(mu_q(x_prev, x_next) | prior(x_prev)) with its gradient with respect to the
ground-frame states, for one frame pair and for a sequence (default 600 frames = 599 pairs), on random
weights of the official size (9.7M parameters, float32 on disk as the official checkpoint, evaluated in
float64 by both sides). Prints medians and the ratio torch / C++ (> 1: C++ is faster).

    PYTHONPATH=python python3 bench/models_humor.py [--frames 600] [--reps 20] [--threads N]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--reps", type=int, default=20, help="repetitions for the single pair (fewer for sequences)")
    parser.add_argument("--threads", type=int, default=None, help="threads for both torch and the C++ (OpenMP)")
    return parser.parse_args()


ARGS = parse_args()
if ARGS.threads:  # must precede loading the C++ extension and torch's thread pool
    os.environ["OMP_NUM_THREADS"] = str(ARGS.threads)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m3c.body.torch_lbs import axis_angle_to_matrix  # noqa: E402
from m3c.models import humor_state as hs  # noqa: E402
from m3c.models.export import export_weights  # noqa: E402
from m3c.models.humor import HumorModel, transition_nll  # noqa: E402
from m3c.nn import HumorPrior  # noqa: E402


def median_time(fn, reps: int) -> float:
    fn()  # warm-up (allocations, thread pools)
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def random_states(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, hs.STATE_DIM, generator=g, dtype=torch.float64) * 0.3
    x[:, hs.ROOT_ORIENT] = axis_angle_to_matrix(torch.randn(n, 3, generator=g, dtype=torch.float64)).reshape(n, 9)
    x[:, hs.POSE_BODY] = axis_angle_to_matrix(
        0.5 * torch.randn(n, 21, 3, generator=g, dtype=torch.float64)).reshape(n, 189)
    return x


def main() -> int:
    if ARGS.threads:
        torch.set_num_threads(ARGS.threads)
    torch.manual_seed(0)
    model32 = HumorModel().eval()
    with tempfile.TemporaryDirectory() as tmp:
        export_weights(tmp, humor=model32)
        cpp = HumorPrior(Path(tmp) / "humor.safetensors")
    model = model32.double().requires_grad_(False)

    print(f"torch {torch.__version__}, torch threads {torch.get_num_threads()}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, cores {os.cpu_count()}")

    def torch_term_and_grad(prev: torch.Tensor, nxt: torch.Tensor):
        a = prev.clone().requires_grad_(True)
        b = nxt.clone().requires_grad_(True)
        value = transition_nll(model, a, b).sum()
        value.backward()
        return value.detach(), a.grad, b.grad

    rows = []
    # One frame pair.
    pair = random_states(2, 1)
    prev, nxt = pair[:1], pair[1:]
    prev_np, nxt_np = prev.numpy(), nxt.numpy()
    t_torch = median_time(lambda: torch_term_and_grad(prev, nxt), ARGS.reps)
    t_cpp = median_time(lambda: cpp.transition_nll(prev_np, nxt_np, with_gradient=True), ARGS.reps)
    value_t, ga_t, gb_t = torch_term_and_grad(prev, nxt)
    value_c, ga_c, gb_c = cpp.transition_nll(prev_np, nxt_np, with_gradient=True)
    err = max(np.abs(ga_c - ga_t.numpy()).max() / np.abs(ga_t.numpy()).max(),
              np.abs(gb_c - gb_t.numpy()).max() / np.abs(gb_t.numpy()).max())
    rows.append(("1 pair: term + gradient", t_torch, t_cpp, err))
    with torch.no_grad():
        t_torch_v = median_time(lambda: transition_nll(model, prev, nxt), ARGS.reps)
    t_cpp_v = median_time(lambda: cpp.transition_nll(prev_np, nxt_np), ARGS.reps)
    rows.append(("1 pair: term only", t_torch_v, t_cpp_v, float("nan")))

    # A sequence: the sum over its consecutive pairs and the gradient for every state.
    states = random_states(ARGS.frames, 2)
    states_np = states.numpy()
    seq_reps = max(3, ARGS.reps // 5)

    def torch_sequence():
        s = states.clone().requires_grad_(True)
        total = transition_nll(model, s[:-1], s[1:]).sum()
        total.backward()
        return total.detach(), s.grad

    t_torch_s = median_time(torch_sequence, seq_reps)
    t_cpp_s = median_time(lambda: cpp.sequence_transition_nll(states_np), seq_reps)
    total_t, grad_t = torch_sequence()
    total_c, grad_c = cpp.sequence_transition_nll(states_np)
    err_s = float(np.abs(grad_c - grad_t.numpy()).max() / np.abs(grad_t.numpy()).max())
    rows.append((f"{ARGS.frames} frames: term + gradient", t_torch_s, t_cpp_s, err_s))

    print(f"{'case':34s} {'torch autograd':>15s} {'C++':>12s} {'torch/C++':>10s} {'grad rel. diff':>15s}")
    for name, tt, tc, e in rows:
        print(f"{name:34s} {tt * 1e3:12.3f} ms {tc * 1e3:9.3f} ms {tt / tc:10.2f} {e:15.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
