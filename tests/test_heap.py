"""graphsvc.heap: freed memory handed back to the system."""

import platform
import sys

import numpy as np
import pytest

from graphsvc.heap import release_free_memory


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc's malloc_trim only"
)
def test_freed_heap_pages_leave_the_resident_set():
    def resident() -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1])

    x = np.ones(60_000)
    del x  # (a mapped block freed: glibc raises its mmap threshold past this size)
    parts = [np.ones(60_000) for _ in range(2_000)]  # ≈ 0.96 GB of 480 kB arrays, on the heap
    last = parts[-1]  # (held: the heap's top is not free, so nothing is trimmed on its own)
    before = resident()
    parts.clear()
    freed = resident()
    assert before - freed < 0.1e9 / 4096  # freed, but still resident
    assert release_free_memory()
    assert freed - resident() > 0.8e9 / 4096  # handed back
    assert last.sum() == 60_000
