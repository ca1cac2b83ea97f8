"""What every command shares: exit codes, the --out check, logging."""

from __future__ import annotations

import sys
from pathlib import Path

# Exit codes: 0 success, 1 internal error (a bug: please report it with the traceback), 2 bad input or
# configuration, 3 a component or model file the run needs is not available, 130 interrupted.
EXIT_INPUT, EXIT_UNAVAILABLE = 2, 3


def setup_logging(verbosity: int) -> None:
    import logging

    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    logging.basicConfig(level=level, format="%(name)s: %(message)s", stream=sys.stderr)


def output_folder(path: str | Path) -> Path:
    """`path` as an output folder this process can create and write; ValueError naming the problem otherwise
    (an existing file, a folder under a file, no write permission, a read-only file system)."""
    import os
    import tempfile

    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"--out {path} is a file, not a folder; choose a folder (it is created if missing)")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"--out {path} lies under {existing}, which is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--out {path}: no permission to write in {existing}; choose a writable folder")
    try:
        with tempfile.TemporaryFile(dir=existing):  # a read-only file system passes os.access for root
            pass
    except OSError as err:
        raise ValueError(f"--out {path}: cannot write in {existing}: {err.strerror or err}") from None
    return path


def log_to_stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def provenance(args) -> dict:
    """Where a benchmark's JSON came from: the command line, M3C's version and, in a git checkout, the commit
    (tools/benchmark_tables.py prints them above every table it makes from the JSON)."""
    import subprocess

    from m3c import __version__

    commit = None
    try:
        done = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10)
        if done.returncode == 0:
            commit = done.stdout.strip() or None
            dirty = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "status", "--porcelain",
                                    "--untracked-files=no"], capture_output=True, text=True, timeout=10)
            if commit and dirty.returncode == 0 and dirty.stdout.strip():
                commit += "+changes"  # uncommitted edits: the commit alone does not reproduce it
    except (OSError, subprocess.SubprocessError):
        pass
    argv = getattr(args, "argv", None)
    return {"command": "m3c " + " ".join(argv) if argv else None, "m3c_version": __version__, "commit": commit}
