"""Keeping freed memory in the process instead of handing it back to the system.

A pass allocates and frees large arrays (a screen region's samples, the
multisample buffers, the sample tester's tile-major copies), and the threads
of a pass (the run-ahead threads, sample generation's) are new in each pass.
With glibc's default malloc, an array above the mmap threshold is mapped on
allocation and unmapped when freed, and a thread's arena gives its free top
back, so the next region or pass touches fresh pages again; a page touched
for the first time costs a page fault, which on the virtual machines this
runs on took several microseconds each (docs/performance.md). Setting one
malloc arena for all threads, no mmap-backed allocations and no trimming
keeps freed memory in the process's heap for the next allocation: the
images and counters are the same, the resident memory stays at its peak.
"""

from __future__ import annotations

import ctypes
import sys

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
_NEVER_TRIM = 2**31 - 1  # the largest value mallopt takes (an int): a free top of 2 GiB


def keep_freed_memory() -> bool:
    """Configure glibc's malloc to keep freed memory for reuse; True if it did (False elsewhere: another C
    library, another system). Call it once, early, before the threads of a pass start."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in (
        (_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, _NEVER_TRIM)))
