"""The sweep's local worker processes: forked from the sweep (each inherits its parsed
experiment and imports), closing their copy of the folder's lock and leaving with the sweep.

Why a module: the lanes (:mod:`.lanes`) and the points run one by one (:mod:`.grid`) both run
in such a pool.
"""
from __future__ import annotations

import contextlib
import gc
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Iterator

from mgpusim.io import collector

#: The collector's thresholds while points run (gen0 allocations, then gen1 and gen2 sweeps).
POINT_GC_THRESHOLDS = (50_000, 50, 100)


def fewer_collections() -> contextlib.AbstractContextManager[None]:
    """Points run with the objects that exist now (modules, the parsed experiment) frozen out
    of the cyclic collector and collections at :data:`POINT_GC_THRESHOLDS`, the collector as it
    was afterwards (:func:`mgpusim.io.collector.fewer_collections`). A point at the analytic
    level allocates thousands of small objects: with the default thresholds the collector took
    about a quarter of a sweep over scene keys (min of 4 runs, in one process: 1.93 s CPU by
    default, 1.35 s so, 1.35 s with the collector off)."""
    return collector.fewer_collections(POINT_GC_THRESHOLDS[0], POINT_GC_THRESHOLDS[1:])


@contextlib.contextmanager
def local_pool(workers: int, store: Any = None) -> Iterator[ProcessPoolExecutor]:
    """`workers` processes; `store`: the sweep's locked folder (None without one), whose lock
    the workers must not keep alive. Pending work is cancelled if the caller stops early."""
    lock = _lock_identity(store)
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_exit_with_parent,
                               initargs=(os.getpid(), lock))
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _lock_identity(store: Any) -> tuple[int, int, int] | None:
    """(descriptor, device, inode) of the folder's lock, for the pool workers to close."""
    if store is None or store.lock_fd is None:
        return None
    st = os.fstat(store.lock_fd)
    return store.lock_fd, st.st_dev, st.st_ino


def _exit_with_parent(parent: int, lock: tuple[int, int, int] | None = None) -> None:
    """In a pool worker: collect garbage as :func:`fewer_collections` does, close its
    inherited copy of the folder's lock descriptor (so that the
    lock ends with the sweep itself, even with SIGKILL, not with its last worker; closed only
    if that descriptor is the lock file, as it is where workers are forked), and exit when the
    sweep's process is gone (killed with SIGKILL, its workers would otherwise wait on their
    queue forever)."""
    gc.freeze()  # (what the worker inherited: see fewer_collections)
    gc.set_threshold(*POINT_GC_THRESHOLDS)
    if lock is not None:
        fd, dev, ino = lock
        with contextlib.suppress(OSError):
            st = os.fstat(fd)
            if (st.st_dev, st.st_ino) == (dev, ino):
                os.close(fd)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)
    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()
