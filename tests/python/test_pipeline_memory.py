"""The runner hands freed heap memory back to the system after every node (release_heap): glibc gives back only the
free memory at the top of its heap, so one block still in use above a node's freed gigabytes (an output, a cached
object) would keep the process at that node's peak for the rest of the run (seen after the ground node of a
10-minute video: 2.5 GB resident for the nodes after it)."""

import re
from pathlib import Path

import numpy as np
import pytest
from m3c.pipeline.runner import release_heap


def rss_mb() -> float:
    return int(re.search(r"VmRSS:\s+(\d+) kB", Path("/proc/self/status").read_text()).group(1)) / 1024


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads the resident memory from /proc (Linux)")
def test_freed_heap_goes_back_to_the_system():
    arrays = [np.ones(4000) for _ in range(8000)]  # 256 MB in 32 kB blocks, from the heap
    kept_above = np.ones(4000)  # allocated after them: the top of the heap stays in use
    held = rss_mb()
    del arrays
    kept = rss_mb()
    if not release_heap():
        pytest.skip("not glibc: no malloc_trim")
    assert kept > held - 64  # freed, but still the process's
    assert rss_mb() < kept - 192
    assert kept_above.sum() == 4000
