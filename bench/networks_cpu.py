"""Per-frame CPU time of the thesis's networks at full size (random weights, float32, batch 1), against a plain
ViT-B forward pass (256 x 192) measured in the same process: ViTPose-B/L/H (one person: the image and its mirror,
as the flip test runs them, and the heatmap decoding), HMR 2.0 (ViT-H + SMPL decoder), DPVO's encoders on one
frame at the VO's processing size, DPVO's update step (correlation + operator) over one frame's edges, and M3C's
patch VO with DPVO's networks as its front-end on the bundled clip (whole-frame time, bundle adjustment included).

    PYTHONPATH=python python3 bench/networks_cpu.py [--threads 2] [--reps 3] [--vo-frames 30]
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from pathlib import Path


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--reps", type=int, default=3, help="timed repetitions per network (median)")
    parser.add_argument("--vo-frames", type=int, default=30, help="frames of the clip for the VO run (0: skip)")
    parser.add_argument("--only", nargs="*", default=None, help="names of the rows to run (default: all)")
    return parser.parse_args()


ARGS = parse_args()
os.environ.setdefault("OMP_NUM_THREADS", str(ARGS.threads))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m3c.models.dpvo import DPVONet, correlation, patch_features  # noqa: E402
from m3c.models.hmr2 import HMR2  # noqa: E402
from m3c.models.vit import ViT, ViTConfig, parameter_count  # noqa: E402
from m3c.models.vitpose import ViTPose, decode_heatmaps  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pexels_walking_moving_camera.mp4"


REFERENCE = None  # the ViT-B forward, timed right before every timed repetition


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def median_time(fn, reps: int) -> tuple[float, float]:
    """Median seconds of fn and median ratio to the reference, each repetition paired with a reference run just
    before it (the machine's load then weighs on both alike)."""
    fn()  # warm-up
    times, ratios = [], []
    for _ in range(reps):
        ref = _timed(REFERENCE) if REFERENCE is not None else None
        t = _timed(fn)
        times.append(t)
        ratios.append(t / ref if ref else 1.0)
    return float(np.median(times)), float(np.median(ratios))


def clip_frames(count: int, side: int = 640):
    import cv2

    cap = cv2.VideoCapture(str(EXAMPLE))
    frames = []
    while len(frames) < count:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    if not frames:
        sys.exit(f"cannot read {EXAMPLE}")
    return frames


def main() -> None:
    torch.set_num_threads(ARGS.threads)
    torch.manual_seed(0)
    rows = []
    wanted = set(ARGS.only) if ARGS.only else None

    def record(name, params, seconds, ratio):
        rows.append((name, params, seconds, ratio))
        count = f"{params / 1e6:7.1f} M" if params else " " * 9
        print(f"{name:58s} {count}  {seconds * 1e3:9.0f} ms  {ratio:6.2f} x ViT-B", flush=True)

    def run(name, build, fn, params):
        if wanted is not None and name not in wanted:
            return
        model = build()
        record(name, params(model), *median_time(lambda: fn(model), ARGS.reps))
        del model
        gc.collect()

    global REFERENCE
    image = torch.randn(1, 3, 256, 192)
    with torch.no_grad():
        reference = ViT(ViTConfig.size("base")).eval()
        REFERENCE = lambda: reference(image)  # noqa: E731
        REFERENCE, fn = None, REFERENCE
        record("ViT-B forward (reference)", parameter_count(reference), median_time(fn, ARGS.reps)[0], 1.0)
        REFERENCE = fn
        for size, letter in (("base", "B"), ("large", "L"), ("huge", "H")):
            run(f"ViTPose-{letter} (flip test + decoding)", lambda s=size: ViTPose(ViTConfig.size(s)).eval(),
                lambda m: decode_heatmaps(m.heatmaps(image, flip_test=True).numpy()), parameter_count)
        run("HMR 2.0 (ViT-H + decoder, 256 x 256)", lambda: HMR2().eval(), lambda m: m(torch.randn(1, 3, 256, 256)),
            parameter_count)

        frames = clip_frames(max(ARGS.vo_frames, 2))
        import cv2

        small = [cv2.resize(f, (640, 360), interpolation=cv2.INTER_AREA)[:360 // 4 * 4] for f in frames]
        batch = torch.from_numpy(np.stack(small[:1]))
        run("DPVO encoders (640 x 360 frame)", lambda: DPVONet().eval(), lambda m: m.encode(batch), parameter_count)

        # One update step over one frame's edges as DPVO sizes them: 96 patches of each of the last 13 frames
        # measured in the new frame.
        def dpvo_update(model, edges=96 * 13):
            fmap, imap = model.encode(torch.from_numpy(np.stack(small[:2])))
            rng = np.random.default_rng(0)
            centres = torch.from_numpy(np.column_stack([rng.uniform(2, 157, edges), rng.uniform(2, 87, edges)])
                                       ).float()
            gmap, context = patch_features(fmap[0], imap[0], centres)
            grid = torch.stack(torch.meshgrid(torch.arange(-1.0, 2.0), torch.arange(-1.0, 2.0),
                                              indexing="ij")[::-1], -1)
            kk = torch.arange(edges)
            ii = torch.div(kk, 96, rounding_mode="floor")
            jj = torch.full((edges,), 13)
            state = torch.zeros(1, edges, 384)

            def step():
                corr = correlation(gmap, fmap[1], centres[:, None, None] + grid)
                return model.update(state, context[None], corr[None], ii, jj, kk)
            return step

        if wanted is None or "DPVO update step (1248 edges)" in wanted:
            model = DPVONet().eval()
            record("DPVO update step (1248 edges)", parameter_count(model.update),
                   *median_time(dpvo_update(model), ARGS.reps))

    if ARGS.vo_frames and (wanted is None or "patch VO with DPVO front-end" in wanted):
        from m3c.vo import VOConfig
        from m3c.vo.dpvo import DPVOFrontEnd
        from m3c.vo.odometry import VisualOdometry

        for name, make in (("patch VO, Lucas-Kanade front-end", lambda: None),
                           ("patch VO with DPVO front-end", lambda: DPVOFrontEnd(DPVONet().eval()))):
            front = make()
            ref = _timed(REFERENCE)
            vo = VisualOdometry(None, VOConfig(), bgr=True, front_end=front)
            start = time.perf_counter()
            for frame in frames[:ARGS.vo_frames]:
                vo.add_frame(frame)
            vo.finish()
            per_frame = (time.perf_counter() - start) / ARGS.vo_frames
            record(f"{name} (per frame, {ARGS.vo_frames} frames)", 0, per_frame, per_frame / ref)

    print(f"\n{ARGS.threads} threads, torch {torch.__version__}, median of {ARGS.reps}; x ViT-B = median ratio "
          "to a ViT-B forward timed right before each repetition")
    print("| network | parameters | ms per frame | x ViT-B |")
    print("|---|---|---|---|")
    for name, params, seconds, ratio in rows:
        count = f"{params / 1e6:.1f} M" if params else ""
        print(f"| {name} | {count} | {seconds * 1e3:.0f} | {ratio:.2f} |")


if __name__ == "__main__":
    main()
