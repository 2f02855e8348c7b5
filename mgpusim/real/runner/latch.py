"""`Latch`: a flag set once that threads wait for, made of one C lock.

Why not `threading.Event`: the runner meets on two per task (submitted, completed), and an
Event is a Condition written in Python: each wait allocates a lock, queues it and takes the
condition's own lock around it, each set walks the waiters. With light 4-GPU frames the runner's
threads kept the interpreter busy for most of the run, and what a woken thread then waits for is
the interpreter (docs/nvidia_h200_x4.md, "The threads wait for the interpreter"). A Latch does
the same with one lock acquired at birth and released once by `set`: a waiter takes it and gives
it straight back, so every waiter gets through, each in C.
"""
from __future__ import annotations

import _thread


class Latch:
    """`set()` once (further calls do nothing, from any thread); `wait(timeout)` returns True
    once it is set, False if `timeout` seconds passed first; `is_set()` looks without waiting."""

    __slots__ = ("_flag", "_lock", "_token")

    def __init__(self) -> None:
        self._flag = False
        self._lock = _thread.allocate_lock()
        self._lock.acquire()
        #: popped by the one `set` that releases the lock (list.pop is atomic): a second
        #: release would free a lock some waiter holds
        self._token = [None]

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        try:
            self._token.pop()
        except IndexError:
            return
        self._flag = True
        self._lock.release()

    def wait(self, timeout: float) -> bool:
        if self._flag:
            return True
        if self._lock.acquire(True, timeout):
            self._lock.release()
            return True
        return self._flag
