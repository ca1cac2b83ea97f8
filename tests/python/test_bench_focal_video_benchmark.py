"""bench/focal_video_benchmark.py on two made-up finished runs: each run's focal length, source and errors against
its truth, and the per-source means."""

import importlib.util
import json
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[2] / "bench" / "focal_video_benchmark.py"


def _run(out: Path, name: str, true: float, camera: dict) -> None:
    (out / "runs" / name).mkdir(parents=True)
    (out / "videos" / name).mkdir(parents=True)
    (out / "runs" / name / "results.json").write_text(json.dumps({"camera": camera}))
    np.savez(out / "videos" / name / "truth.npz", intrinsics=np.array([true, true, 480.0, 270.0]))


def test_focal_table_and_means(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("focal_video_benchmark", SCRIPT)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "vb"
    search = {"focal": 1100.0, "default": 1100.0, "log_sigma": None, "informative": False, "still": True}
    _run(out, "seq00_static_1p-aaaa", 800.0,
         {"intrinsics": [880.0, 880.0, 480.0, 270.0], "intrinsics_source": "people", "focal_estimate": search,
          "scene": {"focal": None, "informative": False},
          "feet_focal": {"measured": 840.0, "log_sigma": 0.05, "informative": True, "default": 1100.0}})
    _run(out, "seq01_pan_3p-bbbb", 1000.0,
         {"intrinsics": [990.0, 990.0, 480.0, 270.0], "intrinsics_source": "estimated",
          "focal_estimate": {**search, "focal": 990.0, "log_sigma": 0.02, "informative": True, "still": False}})
    assert bench.main([str(out)]) == 0
    text = capsys.readouterr().out
    static = next(line for line in text.splitlines() if line.startswith("vb/seq00_static_1p"))
    assert "880" in static and "people" in static and "+10.0" in static and "+37.5" in static
    assert "840 (0.05)" in static and "1100 (no)" in static
    assert "people      1 sequences: mean |error|  10.0% (the default's  37.5%)" in text
    assert "estimated   1 sequences: mean |error|   1.0% (the default's  10.0%)" in text
    assert bench.main([str(tmp_path / "nothing")]) == 1
