"""The runner's `Latch`: every waiter gets through once it is set, from any thread, and a
second `set` (two threads finding one task done) changes nothing."""
from __future__ import annotations

import threading
import time

from mgpusim.real.runner.latch import Latch


def test_a_wait_times_out_until_the_latch_is_set():
    latch = Latch()
    start = time.monotonic()
    assert not latch.wait(0.02) and not latch.is_set()
    assert time.monotonic() - start >= 0.015
    latch.set()
    assert latch.is_set() and latch.wait(0) and latch.wait(5)


def test_every_waiter_gets_through_one_set():
    latch = Latch()
    woke: list[bool] = []
    threads = [threading.Thread(target=lambda: woke.append(latch.wait(5))) for _ in range(8)]
    for t in threads:
        t.start()
    time.sleep(0.02)
    latch.set()
    for t in threads:
        t.join(5)
    assert woke == [True] * 8


def test_sets_from_many_threads_release_once():
    """A second release would free the lock a waiter holds, and the waiter's own release
    would then raise."""
    for _ in range(200):
        latch = Latch()
        errors: list[BaseException] = []

        def both(latch: Latch = latch, errors: list[BaseException] = errors) -> None:
            try:
                latch.set()
                assert latch.wait(1)
            except BaseException as exc:  # noqa: BLE001 - reported below
                errors.append(exc)
        threads = [threading.Thread(target=both) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(5)
        assert errors == [] and latch.is_set() and not latch._lock.locked()
