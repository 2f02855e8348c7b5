"""Host-to-host copies on K threads, in chunks of at least 512 KiB (docs/sources.md: the five-step pipeline, step 3).

Why threads work here: numpy's copy of a large slice releases the GIL, so K Python threads copy
in parallel, as the thesis's reference code does with native threads; one thread alone cannot
saturate memory bandwidth.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from mgpusim.model.errors import InputError

MIN_CHUNK = 512 * 1024


class HostCopier:
    """A pool of `threads` copy threads; `copy(dst, src)` returns its (start, end) monotonic ns."""

    def __init__(self, threads: int, min_chunk: int = MIN_CHUNK):
        if threads < 1:
            raise InputError(f"threads must be >= 1, got {threads}", field="threads")
        self.threads, self.min_chunk = threads, min_chunk
        self._pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="hostcopy")

    def chunks(self, nbytes: int) -> list[tuple[int, int]]:
        """(start, stop) byte ranges: one per thread, none smaller than min_chunk (bar the last)."""
        size = max(self.min_chunk, -(-nbytes // self.threads))
        return [(s, min(s + size, nbytes)) for s in range(0, nbytes, size)]

    def copy(self, dst: np.ndarray, src: np.ndarray) -> tuple[int, int]:
        d, s = dst.reshape(-1).view(np.uint8), src.reshape(-1).view(np.uint8)
        if d.size != s.size:
            raise InputError(f"host copy of {s.size} bytes into {d.size} bytes")
        start = time.monotonic_ns()
        futures = [self._pool.submit(np.copyto, d[a:b], s[a:b]) for a, b in self.chunks(s.size)]
        for f in futures:
            f.result()
        return start, time.monotonic_ns()

    def close(self) -> None:
        self._pool.shutdown(wait=True)


class HostCopy:
    """The `host_copy` workload: `bytes` between two host arrays on `threads` threads."""

    queue = "host"

    def __init__(self, bytes: int, threads: int = 1):  # noqa: A002 - the parameter's name
        if bytes <= 0:
            raise InputError(f"bytes must be positive, got {bytes}", field="bytes")
        self.bytes = int(bytes)
        self.src = np.full(self.bytes, 7, dtype=np.uint8)
        self.dst = np.zeros(self.bytes, dtype=np.uint8)
        self.copier = HostCopier(threads)

    def run(self) -> tuple[int, int]:
        return self.copier.copy(self.dst, self.src)

    def destroy(self) -> None:
        self.copier.close()
