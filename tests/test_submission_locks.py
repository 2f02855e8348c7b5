"""A submission's fence is never reset while another thread looks at it.

Vulkan requires vkResetFences to have the fence to itself; a `poll()` from one thread (the
runner's leaders look at other GPUs' work) must not overlap the reset that `wait()` does in
another (the reap thread, recycling the fence for the next submission). The Khronos validation
layer caught that overlap once in a test run; the window is microseconds there, so this test
stands in fake Vulkan calls whose fence look lasts 50 ms and which records any reset inside it.
Two threads that wait for one submission must likewise reset its fence and give its slot back
once.
"""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import pytest

from mgpusim.real.vulkan import device

SLOT = "slot"  # the calls below take it as it is


class FakeHotPath:
    """The per-task calls a Submission makes (mgpusim.real.vulkan.hotpath), on one fence, with
    overlaps recorded."""

    def __init__(self) -> None:
        self.looking = threading.Event()
        self.overlaps: list[str] = []
        self.resets = 0
        self.lock = threading.Lock()
        self.wait_s, self.timeouts = 0.0, 0
        self.waits = self.inside = self.most_inside = 0

    def fence_signalled(self, _dev, _slot) -> bool:
        self.looking.set()
        time.sleep(0.05)
        self.looking.clear()
        return False

    def wait_fence(self, _dev, _slot, _timeout_ns) -> bool:
        with self.lock:
            self.waits += 1
            self.inside += 1
            self.most_inside = max(self.most_inside, self.inside)
        time.sleep(self.wait_s)
        with self.lock:
            self.inside -= 1
        if self.timeouts:
            self.timeouts -= 1
            return False
        return True

    def read_ticks(self, _dev, _slot) -> tuple[int, int]:
        time.sleep(0.02)  # lavapipe's read blocks until the queue is idle
        return 10, 20

    def reset_fence(self, _dev, _slot) -> None:
        if self.looking.is_set():
            self.overlaps.append("vkResetFences during vkGetFenceStatus")
        self.resets += 1


@pytest.fixture
def fake(monkeypatch):
    calls = FakeHotPath()
    monkeypatch.setattr(device, "hotpath", calls)
    return calls


def _submission() -> tuple[device.Submission, SimpleNamespace]:
    queue = SimpleNamespace(gpu=SimpleNamespace(device="dev"), lock=threading.Lock(), free=[],
                            recorded={})
    return device.Submission(queue, SLOT, "probe"), queue


def test_wait_does_not_reset_the_fence_while_another_thread_polls(fake):
    sub, queue = _submission()
    seen: list[bool] = []
    poller = threading.Thread(target=lambda: seen.append(sub.poll()))
    poller.start()
    assert fake.looking.wait(5), "the poll never looked at the fence"
    assert sub.wait().raw_ticks() == (10, 20)
    poller.join()
    assert fake.overlaps == []
    assert seen == [False]  # it looked before the work was known finished
    assert queue.free == [SLOT] and fake.resets == 1
    assert sub.poll()  # the slot is recycled: finished, without touching the fence again


def test_two_waiters_reset_and_recycle_once(fake):
    sub, queue = _submission()
    threads = [threading.Thread(target=sub.wait) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert fake.resets == 1
    assert queue.free == [SLOT]


def test_threads_waiting_for_one_task_call_the_driver_once(fake):
    """Several threads waiting for one task: one is inside the driver's fence wait, the others
    wait for it in Python, and all of them learn the end from that one wait."""
    fake.wait_s = 0.05
    sub, _queue = _submission()
    seen: list[bool] = []
    threads = [threading.Thread(target=lambda: seen.append(sub.finished(5_000_000_000)))
               for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen == [True] * 4
    assert fake.waits == 1 and fake.most_inside == 1


def test_a_waiter_takes_the_watch_when_the_watcher_times_out(fake):
    """A thread whose own wait is short leaves without the answer; one with time left watches
    the fence in its place and sees the end."""
    fake.wait_s, fake.timeouts = 0.05, 1
    sub, _queue = _submission()
    short: list[bool] = []
    watcher = threading.Thread(target=lambda: short.append(sub.finished(50_000_000)))
    watcher.start()
    time.sleep(0.01)  # the short waiter holds the watch
    assert sub.finished(5_000_000_000)
    watcher.join()
    assert short == [False] and fake.waits == 2 and fake.most_inside == 1
