"""The focal length each video-benchmark run went on with against the true one, and where it came from: the
camera's motion (m3c.vo.focal), the scene's lines (m3c.vo.vanishing), a still camera's people (m3c.vo.ground_focal)
or the default (the image diagonal). Reads finished runs only, so run the benchmark first:

    python3 -m m3c eval video-benchmark --seed 0 --out OUT        # renders and runs (cached under OUT)
    PYTHONPATH=python python3 bench/focal_video_benchmark.py OUT [OUT ...]

Per sequence: the true focal length, the one used and its source, both errors (used and default), and what each
source said (estimate and log-sigma; '-' where it did not run or gave nothing, '(no)' where not informative).
Then per source: the sequences it decided and the mean absolute error of the used focal length against the
default's on them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _said(record: dict | None, value: str, sigma: str | None, informative: str = "informative") -> str:
    if not record or record.get(value) is None:
        return "-"
    text = f"{record[value]:.0f}"
    if sigma and record.get(sigma) is not None:
        text += f" ({record[sigma]:.2f})"
    return text if record.get(informative) else text + " (no)"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="+", type=Path, help="video-benchmark output folders (--out)")
    args = parser.parse_args(argv)
    rows, by_source = [], {}
    for out in args.out:
        for run in sorted((out / "runs").glob("*/results.json")):
            name = run.parent.name
            truth = out / "videos" / name / "truth.npz"
            if not truth.exists():
                continue
            intrinsics = np.atleast_2d(np.load(truth)["intrinsics"])
            true = float(intrinsics[0, 0])
            camera = json.loads(run.read_text())["camera"]
            used, source = float(camera["intrinsics"][0]), camera["intrinsics_source"]
            search, scene, feet = camera.get("focal_estimate"), camera.get("scene"), camera.get("feet_focal")
            default = float((search or feet or {}).get("default") or used)
            error, default_error = 100 * (used / true - 1), 100 * (default / true - 1)
            by_source.setdefault(source, []).append((abs(error), abs(default_error)))
            rows.append((f"{out.name}/{name.rsplit('-', 1)[0]}", true, used, source, error, default_error,
                         _said(search, "focal", "log_sigma"), _said(scene, "focal", None),
                         _said(feet, "measured", "log_sigma")))
    if not rows:
        print("no finished video-benchmark runs under", ", ".join(map(str, args.out)))
        return 1
    header = ("sequence", "true", "used", "source", "err %", "default %", "motion", "scene", "people")
    widths = [max(len(header[0]), *(len(r[0]) for r in rows)), 6, 6, 9, 7, 9, 17, 10, 17]
    print("  ".join(h.ljust(w) for h, w in zip(header, widths)))
    for r in rows:
        cells = (r[0], f"{r[1]:.0f}", f"{r[2]:.0f}", r[3], f"{r[4]:+.1f}", f"{r[5]:+.1f}", *r[6:])
        print("  ".join(str(c).ljust(w) for c, w in zip(cells, widths)))
    print()
    for source, errors in sorted(by_source.items()):
        used, default = np.mean(errors, axis=0)
        print(f"{source:9s} {len(errors):3d} sequences: mean |error| {used:5.1f}% (the default's {default:5.1f}%)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
