"""The process's resident memory from Linux's /proc, for the benchmarks that measure it (long_video.py,
optimizer_memory.py). Kept free of m3c and torch imports: optimizer_memory.py measures a process without torch."""

from __future__ import annotations

import re
from pathlib import Path


def status_mib(field: str) -> float:
    """A memory field of /proc/self/status (VmRSS, VmHWM, ...) in MiB."""
    text = Path("/proc/self/status").read_text()
    return int(re.search(rf"^{field}:\s+(\d+) kB", text, re.M).group(1)) / 1024


def reset_peak() -> None:
    """Resets VmHWM (the peak resident memory) to the current resident memory."""
    Path("/proc/self/clear_refs").write_text("5")
