"""Keep the C heap's freed memory in the process instead of handing it back every frame.

Why: lavapipe's binner allocates each frame's scene memory with malloc and frees it when the
frame ends. Under glibc's defaults (a dynamic mmap threshold, and the heap trimmed whenever
128 KiB lie free at its top) that memory goes back to the kernel after a frame and is faulted
in again, page by page, in the next. On the 2-core development machine a mesh pass of 40,000
triangles then took 9-13.5 ms instead of 7.2 ms (279,000 minor page faults against 35,000 for
the same sweep), and where the cliff sets in (24,000-35,000 triangles) moved with the
allocator's history, so a pass was fast in one frame and 5 ms slower in the next. A GPU's
cost does not jump like that; the runner measures a device, not the host allocator.

So before the first instance is made the runner fixes glibc's thresholds: allocations up to
32 MiB (glibc's upper limit) come from the heap, and the heap is trimmed only past 1 GiB free.
`MGPUSIM_KEEP_HEAP=0` leaves glibc's defaults (to measure the effect); on a C library other than
glibc nothing is changed.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os

#: mallopt parameter numbers (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

#: Largest mmap threshold glibc accepts on 64-bit (4 * 1024 * 1024 * sizeof(long)).
MMAP_THRESHOLD = 32 * 1024 * 1024
TRIM_THRESHOLD = 1024 * 1024 * 1024

@functools.cache
def keep_heap() -> str:
    """Apply the thresholds once per process; returns what was done (for the machine record).
    Two threads making their first instance at once may both set them: same values."""
    if os.environ.get("MGPUSIM_KEEP_HEAP", "1") == "0":
        return "glibc defaults (MGPUSIM_KEEP_HEAP=0)"
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        mallopt = libc.mallopt if libc is not None else None
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is None:
        return "unchanged (no glibc mallopt)"
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # The trim threshold first: a fixed mmap threshold alone also fixes trimming at 128 KiB,
    # which made every frame fault its scene in (584,000 faults in the sweep above).
    if mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) != 1:
        return "unchanged (mallopt refused the trim threshold)"
    if mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) != 1:
        return f"trim_threshold={TRIM_THRESHOLD} only (mallopt refused the mmap threshold)"
    return f"mmap_threshold={MMAP_THRESHOLD} trim_threshold={TRIM_THRESHOLD}"
