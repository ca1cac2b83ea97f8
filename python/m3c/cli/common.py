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


def source_commit(source: str | Path) -> str | None:
    """The short commit of the git checkout that tracks `source` ("+changes" with uncommitted edits), or None. A
    repository that merely contains the file does not count: an installed M3C under a pyenv clone would report
    pyenv's commit."""
    import subprocess

    source = Path(source).resolve()
    folder = str(source.parent)
    try:
        tracked = subprocess.run(["git", "-C", folder, "ls-files", "--error-unmatch", source.name],
                                 capture_output=True, text=True, timeout=10)
        if tracked.returncode != 0:
            return None
        done = subprocess.run(["git", "-C", folder, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10)
        commit = done.stdout.strip() if done.returncode == 0 else ""
        if not commit:
            return None
        dirty = subprocess.run(["git", "-C", folder, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)
        if dirty.returncode == 0 and dirty.stdout.strip():
            commit += "+changes"  # uncommitted edits: the commit alone does not reproduce it
        return commit
    except (OSError, subprocess.SubprocessError):
        return None


def provenance(args) -> dict:
    """Where a benchmark's JSON came from: the command line, M3C's version and, in a git checkout of M3C, the
    commit (tools/benchmark_tables.py prints them above every table it makes from the JSON)."""
    from m3c import __version__

    commit = source_commit(__file__)
    argv = getattr(args, "argv", None)
    return {"command": "m3c " + " ".join(argv) if argv else None, "m3c_version": __version__, "commit": commit}
