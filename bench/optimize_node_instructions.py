"""Instructions the pipeline's optimize node executes, counted by callgrind (valgrind), so that two builds compare
on a loaded machine: `m3c run VIDEO --out RUN --until optimize` with one optimizer thread, once with the node's
cache entry removed and once with it cached; the node's count is the difference. The earlier nodes must already be
cached in RUN (run the pipeline there once first), and each count takes minutes (valgrind runs ~50x slower).

    python bench/optimize_node_instructions.py RUN [--video examples/pexels_walking_moving_camera.mp4]

Compare builds by running it with each build's m3c first on the path (PYTHONPATH), each on its own copy of RUN.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def count(run: Path, video: Path, out_file: Path) -> int:
    """Callgrind's total instruction count of one `m3c run ... --until optimize` (one optimizer thread)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_WAIT_POLICY="passive")
    # The interpreter itself, not a launcher script: valgrind does not follow exec.
    python = os.path.realpath(sys.executable)
    cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out_file}", python, "-m", "m3c", "run",
           str(video), "--out", str(run), "--until", "optimize", "--set", "optimize.optimizer={num_threads: 1}", "-q"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"the counted run failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    match = re.search(r"^totals:\s*(\d+)", out_file.read_text(), re.MULTILINE)
    if match is None:
        sys.exit(f"no 'totals:' line in {out_file}")
    return int(match.group(1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run folder whose nodes before optimize are cached")
    parser.add_argument("--video", type=Path, default=ROOT / "examples" / "pexels_walking_moving_camera.mp4")
    args = parser.parse_args()
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not installed (apt-get install valgrind)")
    if not (args.run / "cache").is_dir():
        sys.exit(f"{args.run} holds no pipeline cache: run `m3c run {args.video} --out {args.run}` there first")
    with tempfile.TemporaryDirectory() as tmp:
        shutil.rmtree(args.run / "cache" / "optimize", ignore_errors=True)
        with_node = count(args.run, args.video, Path(tmp) / "node.out")
        cached = count(args.run, args.video, Path(tmp) / "cached.out")
    print(f"m3c from {importlib.util.find_spec('m3c').origin}")
    print(f"instructions: run with the optimize node {with_node / 1e9:.3f} G, with it cached {cached / 1e9:.3f} G, "
          f"the node {(with_node - cached) / 1e9:.3f} G")


if __name__ == "__main__":
    main()
