"""Runs Python code in a child process, so that a crash in the C++ core (a segfault, an abort) fails the test that
caused it instead of killing pytest. The child imports the same m3c as the tests and has a fault handler on."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import m3c

PYTHON_DIR = str(Path(m3c.__file__).resolve().parents[1])


def run_isolated(code: str, timeout: float = 120.0) -> dict:
    """Executes `code`; the value it assigns to `result` (JSON-serialisable) comes back as ["ok", result], an
    exception as [type name, message]. A crash raises AssertionError with the exit status and the child's stderr."""
    script = (f"import faulthandler, json, sys\nfaulthandler.enable()\nsys.path.insert(0, {PYTHON_DIR!r})\n"
              f"result = None\ntry:\n" + "".join(f"    {line}\n" for line in code.strip().splitlines()) +
              "    outcome = ['ok', result]\nexcept Exception as err:\n"
              "    outcome = [type(err).__name__, str(err)]\n"
              "print('@@' + json.dumps(outcome, default=str))\n")
    env = {**os.environ, "PYTHONFAULTHANDLER": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=timeout, env=env)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("@@")]
    if proc.returncode != 0 or not lines:
        raise AssertionError(f"the child process crashed (exit status {proc.returncode}) running:\n{code}\n"
                             f"stderr:\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1][2:])
