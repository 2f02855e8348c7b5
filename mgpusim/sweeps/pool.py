"""The sweep's local worker processes: forked from the sweep (each inherits its parsed
experiment and imports), closing their copy of the folder's lock and leaving with the sweep.

Why a module: the lanes (:mod:`.lanes`) and the points run one by one (:mod:`.grid`) both run
in such a pool.
"""
from __future__ import annotations

import contextlib
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Iterator


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
    """In a pool worker: close its inherited copy of the folder's lock descriptor (so that the
    lock ends with the sweep itself, even with SIGKILL, not with its last worker; closed only
    if that descriptor is the lock file, as it is where workers are forked), and exit when the
    sweep's process is gone (killed with SIGKILL, its workers would otherwise wait on their
    queue forever)."""
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
