"""The world view's cost: the chase view (framed on the people, footprints, trails, inset) against the fixed
overview it replaced as the default, on one run's cached results, alternating (these machines are noisy), printed
as a ratio of the world_view node's time in the same process.

    python bench/world_view.py [VIDEO] [--out /tmp/bench_world_view] [--repeats 2]

The first call runs the pipeline up to the world view (cached in --out); each repeat then reruns only the
world_view node, once per view.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import time
from pathlib import Path

from m3c.nodes import register_builtin_nodes
from m3c.pipeline import PipelineConfig, Runner

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pexels_walking_moving_camera.mp4"


def node_seconds(config: PipelineConfig, out: Path, video: Path) -> float:
    shutil.rmtree(out / "cache" / "world_view", ignore_errors=True)
    started = time.perf_counter()
    report = Runner(config, out, {"video": video}, show_progress=False).run(["world_view"])
    record = next(r for r in report.records if r.name == "world_view")
    assert record.status == "ran", record
    return record.seconds if record.seconds > 0 else time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video", nargs="?", type=Path, default=EXAMPLE)
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_world_view"))
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    register_builtin_nodes()
    base = PipelineConfig.default()
    views = {name: base.with_overrides({"world_view.view": name}) for name in ("overview", "chase")}
    Runner(base, args.out, {"video": args.video}, show_progress=False).run(["optimize"])
    times = {name: [] for name in views}
    for _ in range(args.repeats):
        for name, config in views.items():
            times[name].append(node_seconds(config, args.out, args.video))
    for name, values in times.items():
        print(f"{name:9s} world_view node: " + ", ".join(f"{v:.2f} s" for v in values))
    ratio = statistics.median(times["chase"]) / statistics.median(times["overview"])
    print(f"chase / overview: {ratio:.2f}x (medians of {args.repeats})")


if __name__ == "__main__":
    main()
