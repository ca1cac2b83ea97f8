"""Long videos through `m3c run`: peak memory and time of every node on a video of a given length.

The video is the bundled example played forwards then backwards, again and again (no frame repeated at a turn),
resized to 960 x 540, until it lasts --minutes. The default pipeline runs on it in this process as `m3c run` does
(a fresh output folder). For every node the script prints:

    seconds         the node's run time
    s/min           seconds per minute of video (run time / video minutes)
    peak RSS        the process's peak resident memory while the node ran (VmHWM, reset at the node's start
                    through /proc/self/clear_refs), including the inputs it loads from the cache
    RSS 1st/4th q   the process's mean resident memory in the first and the last quarter of the node's run
                    (sampled every 0.2 s): equal figures mean its memory does not grow with the frames it has seen
    cores           the process's CPU time over the node's run time: how many cores it kept busy (on a machine
                    shared with other work it is lower than on an idle one)

Run it on two lengths to see what grows with the video's length:

    nice -n 10 python bench/long_video.py --minutes 1 --out /tmp/long1
    nice -n 10 python bench/long_video.py --minutes 2 --out /tmp/long2

--keep-video reuses the video under OUT when it is there; --until NODE stops after NODE (e.g. optimize); --resume
keeps the earlier run's cache, so only the nodes whose cache entries were deleted run (and are measured).
"""

from __future__ import annotations

import argparse
import shutil
import threading
import time
from pathlib import Path

import cv2
import numpy as np
from m3c.io.video import VideoWriter, iter_frames, probe_video
from m3c.nodes import register_builtin_nodes
from m3c.pipeline import PipelineConfig, Runner
from proc_memory import reset_peak, status_mib

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pexels_walking_moving_camera.mp4"
SIZE = (960, 540)


def make_long_video(path: Path, minutes: float, source: Path = EXAMPLE, size=SIZE) -> int:
    """Writes the ping-pong loop of `source` (resized to `size`) lasting `minutes`; returns its frame count.
    Only the source's frames are held in memory (the bundled clip: 178 frames, 277 MB at 960 x 540)."""
    fps = probe_video(source).fps
    frames = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) if f.shape[1::-1] != size else f
              for _, f in iter_frames(source)]
    cycle = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))  # 0..n-1, n-2..1
    total = int(round(minutes * 60 * fps))
    with VideoWriter(path, fps, size) as writer:
        for i in range(total):
            writer.write(frames[cycle[i % len(cycle)]])
    return total


class MeasuredRunner(Runner):
    """Runner that records, per node it runs, the peak RSS and RSS samples over the node's run."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.measures: dict[str, dict] = {}
        self.minutes = 0.0  # the video's length, for the per-minute figures
        self._current: str | None = None
        self._samples: list[tuple[float, float]] = []  # (time, RSS MiB)
        self._stop = threading.Event()
        self._sampler = threading.Thread(target=self._sample, daemon=True)
        self._sampler.start()

    def _sample(self) -> None:
        while not self._stop.wait(0.2):
            if self._current is not None:
                self._samples.append((time.perf_counter(), status_mib("VmRSS")))

    def _gather_inputs(self, name, outputs_of):
        # A node's span starts when its inputs are read from the cache.
        reset_peak()
        self._samples = []
        self._cpu = time.process_time()
        self._start = time.perf_counter()
        self._current = name
        return super()._gather_inputs(name, outputs_of)

    def _run_node(self, node, key, inputs, keys):
        super()._run_node(node, key, inputs, keys)
        self._current = None
        end = time.perf_counter()
        span = end - self._start
        samples = [(t - self._start, rss) for t, rss in self._samples]
        first = [rss for t, rss in samples if t <= span / 4]
        last = [rss for t, rss in samples if t >= 3 * span / 4]
        m = self.measures[node.name] = {
            "seconds": span,
            "cores": (time.process_time() - self._cpu) / span,
            "peak_mb": status_mib("VmHWM"),
            "first_mb": float(np.mean(first)) if first else float("nan"),
            "last_mb": float(np.mean(last)) if last else float("nan"),
        }
        if self.minutes:  # a line as each node ends: a run stopped early still leaves its figures
            print(row(node.name, m, self.minutes), flush=True)

    def close(self) -> None:
        self._stop.set()
        self._sampler.join()


HEADER = (f"{'node':<13} {'seconds':>8} {'s/min':>8} {'peak RSS MB':>12} {'RSS 1st q':>10} {'RSS 4th q':>10} "
          f"{'cores':>6}")


def row(name: str, m: dict, minutes: float) -> str:
    """One node's figures (its span: reading its inputs from the cache, running, committing its outputs)."""
    return (f"{name:<13} {m['seconds']:8.1f} {m['seconds'] / minutes:8.1f} {m['peak_mb']:12.0f} "
            f"{m['first_mb']:10.0f} {m['last_mb']:10.0f} {m['cores']:6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=1.0, help="length of the video (default 1)")
    parser.add_argument("--out", type=Path, required=True, help="work folder (the video and the run's output)")
    parser.add_argument("--keep-video", action="store_true", help="reuse OUT/long.mp4 when it is there")
    parser.add_argument("--until", default=None, help="stop after this node (default: the whole pipeline)")
    parser.add_argument("--resume", action="store_true", help="keep OUT/run: nodes whose outputs are cached there "
                        "are not run again (and not measured); delete a node's cache folder to measure it alone")
    args = parser.parse_args()

    args.out.mkdir(parents=True, exist_ok=True)
    video = args.out / "long.mp4"
    if not (args.keep_video and video.is_file()):
        t0 = time.perf_counter()
        count = make_long_video(video, args.minutes)
        print(f"made {video}: {count} frames, {time.perf_counter() - t0:.0f} s")
    info = probe_video(video)
    run_dir = args.out / "run"
    if not args.resume:
        shutil.rmtree(run_dir, ignore_errors=True)
    register_builtin_nodes()
    runner = MeasuredRunner(PipelineConfig.default(), run_dir, {"video": video}, show_progress=False)
    runner.minutes = info.frame_count_hint / info.fps / 60
    print(f"video: {info.width} x {info.height}, {info.fps:.3f} fps, {info.frame_count_hint} frames = "
          f"{runner.minutes:.2f} min", flush=True)
    print(HEADER, flush=True)
    t0 = time.perf_counter()
    try:
        runner.run([args.until] if args.until else None)
    finally:
        runner.close()
    wall = time.perf_counter() - t0
    total = sum(m["seconds"] for m in runner.measures.values())
    print(f"{'total':<13} {total:8.1f} {total / runner.minutes:8.1f} "
          f"{max(m['peak_mb'] for m in runner.measures.values()):12.0f}")
    print(f"whole run {wall:.0f} s (with the keys, checks and publishing); the process's peak RSS over the run is "
          "the largest peak RSS above")


if __name__ == "__main__":
    main()
