"""python/m3c/_core.pyi (type stubs of the C++ core, as pycolmap ships them) must match the built module: the
stubs are regenerated from the imported m3c._core and compared with the checked-in file."""

import subprocess
import sys
from pathlib import Path

import pytest

import m3c._core

STUBS = Path(__file__).resolve().parents[2] / "python" / "m3c" / "_core.pyi"
REGENERATE = "python -m pybind11_stubgen m3c._core -o python   (from the repository root, with m3c built)"


def test_core_stubs_match_the_built_module(tmp_path):
    pytest.importorskip("pybind11_stubgen", reason="pybind11-stubgen is in the test extra (pip install '.[test]')")
    assert STUBS.is_file(), f"{STUBS} is missing: {REGENERATE}"
    # The module as the tests import it (installed, or the dev build under python/ with PYTHONPATH=python).
    root = Path(m3c._core.__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "pybind11_stubgen", "m3c._core", "-o", str(tmp_path), "--exit-code"],
                          cwd=tmp_path, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"pybind11-stubgen failed (a binding names a C++ type?):\n{done.stderr[-3000:]}"
    generated = (tmp_path / "m3c" / "_core.pyi").read_text()
    assert generated == STUBS.read_text(), f"python/m3c/_core.pyi is out of date with the bindings: {REGENERATE}"
    assert (STUBS.parent / "py.typed").is_file()
