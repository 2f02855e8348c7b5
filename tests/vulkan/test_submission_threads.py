"""Submissions looked at from several threads at once, as the runner does, on real lavapipe.

The runner's leader threads `poll()` another GPU's submission while its reap thread `wait()`s
for it, reads its timestamps and recycles its fence for the next submission. The validation
layer (on for this whole directory) reports any vkResetFences that overlaps another thread's
use of the fence; the session fails at teardown if it did. The window for that overlap is a
few microseconds, so the first test guards it loosely; the second reproduces the failure it
led to every time: two threads that both waited for one submission both reset its fence and
both gave its slot back.
"""
from __future__ import annotations

import threading

import pytest

from mgpusim.real.vulkan import instance as vkinst

pytestmark = pytest.mark.vulkan

ROUNDS = 300


def _empty(cmd) -> None:
    """Nothing between the submission's two timestamps: the shortest work there is."""


def test_poll_never_overlaps_the_fence_reset(gpu):
    before = len(vkinst.validation_errors())
    done = threading.Event()
    current: list = [None]
    seen_finished = 0

    def poller() -> None:
        nonlocal seen_finished
        while not done.is_set():
            sub = current[0]
            if sub is not None and sub.poll():
                seen_finished += 1

    thread = threading.Thread(target=poller)
    thread.start()
    try:
        for i in range(ROUNDS):
            sub = gpu.submit("graphics", _empty, label=f"empty {i}", key="empty")
            current[0] = sub
            start, end = sub.wait().raw_ticks()
            assert end >= start
            assert sub.poll()  # a recycled slot still reads as finished
    finally:
        done.set()
        thread.join()
    assert seen_finished > 0, "the other thread never saw a submission finish"
    assert vkinst.validation_errors()[before:] == []


def test_two_threads_waiting_recycle_the_slot_once(gpu):
    queue = gpu.queue("graphics")
    for i in range(50):
        sub = gpu.submit("graphics", _empty, label=f"twice {i}", key="twice")
        ticks: list = []
        threads = [threading.Thread(target=lambda ticks=ticks, sub=sub: ticks.append(sub.wait().raw_ticks()))
                   for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert ticks[0] == ticks[1]
        idle = queue.recorded.get("twice", [])
        assert len(idle) == len({id(s) for s in idle}), "a slot was given back twice"
