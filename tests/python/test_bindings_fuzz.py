"""Property-based robustness of the C++ boundary (fuzz_core.py, hypothesis): every public bound function and its
Python wrapper, over random dtypes, shapes, layouts and values, returns the canonical input's result or raises a
Python exception. Each group runs in a child process with a fault handler: a segfault or abort fails the group's
test and prints the case that caused it."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import m3c

pytest.importorskip("hypothesis", reason="the property-based suite needs hypothesis (the 'test' extra)")

TESTS_DIR = Path(__file__).resolve().parent
PYTHON_DIR = Path(m3c.__file__).resolve().parents[1]
# Examples per function: enough to reach every dtype, layout and failure path (about 12 s in all on 2 cores).
MAX_EXAMPLES = int(os.environ.get("M3C_FUZZ_EXAMPLES", "100"))


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """Random HuMoR and VPoser weights exported in the layout the C++ runtime reads."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel
    from m3c.models.vposer import VPoserV2

    torch.manual_seed(0)
    out = tmp_path_factory.mktemp("fuzz_weights")
    export_weights(out, humor=HumorModel().double().eval(), vposer=VPoserV2().double().eval(), dtype="float64")
    return out


@pytest.mark.parametrize("group", ["body", "ground", "vo", "nn", "fit_motion", "render"])
def test_no_input_crashes_the_core(group, request):
    args = [sys.executable, str(TESTS_DIR / "fuzz_core.py"), group, str(MAX_EXAMPLES)]
    if group == "nn":
        args.append(str(request.getfixturevalue("weights")))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PYTHON_DIR), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(args, capture_output=True, text=True, timeout=600, env=env)
    cases = [line for line in proc.stdout.splitlines() if line.startswith("CASE")]
    assert proc.returncode == 0 and "ALL PASSED" in proc.stdout, (
        f"exit status {proc.returncode}; last case: {cases[-1] if cases else None}\n{proc.stderr[-4000:]}")
    assert len(cases) >= MAX_EXAMPLES  # the examples really ran
