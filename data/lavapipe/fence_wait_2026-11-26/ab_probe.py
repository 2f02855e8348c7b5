"""Fence waits in turn (under the submission's lock) against all at once, on XR strong scaling.

`Submission.finished` holds the submission's lock while inside vkWaitForFences, so the threads
awaiting one task's end (its reaper and each consumer on another queue) wake one after another.
The trial version (`together`, below) let them wait on the fence at once, counting the waiters
so that `wait()` resets the fence only once none is left. This runs
`experiments/lavapipe/xr.toml` under strong scaling on 2 and 4 lavapipe GPUs (8 rasterizer threads each), alternating run by run between
`turns` (the runner's method) and `together` (patched in from outside), with `../xr_ab.py`,
and writes per run: frame time, latency, and the median hand-off split of the renders bound by
another GPU's task (`seen_us`, `start_us`). Its `case` column is `2gpu` / `4gpu`; the committed
`ab.csv`, written before the loop was shared, names it `gpus` (2 / 4) and has no latency.

    .venv/bin/python data/lavapipe/fence_wait_2026-11-26/ab_probe.py OUT [PAIRS]

A record of one experiment, not part of the package.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import mgpusim.real.vulkan.device as device

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from xr_ab import alternate  # noqa: E402 - the shared A/B loop beside this folder

TURNS = device.Submission.finished


def together(self, timeout_ns):
    """The trial: waiters counted under the lock, the wait itself outside it."""
    with self._lock:
        if self._finished:
            return True
        fence = self._slot[1]
        self._waiters = getattr(self, "_waiters", 0) + 1
    signalled = False
    try:
        device.call("vkWaitForFences", device.vk().vkWaitForFences, self.queue.gpu.device, 1,
                    [fence], device.vk().VK_TRUE, timeout_ns)
        signalled = True
    except device.vk().VkTimeout:
        pass
    finally:
        with self._lock:
            self._waiters -= 1
            self._finished = self._finished or signalled
    return signalled


_WAIT = device.Submission.wait


def wait_for_waiters(self, timeout_ns=60_000_000_000):
    """`wait()` resets the fence: first let every thread inside a wait on it leave."""
    if self._ticks is None and self.finished(timeout_ns):
        while getattr(self, "_waiters", 0):
            time.sleep(0)  # let the waiters have the interpreter to leave their wait
    return _WAIT(self, timeout_ns)


CASES = {"2gpu": ["schedule.scaling=strong", "schedule.gpus=2"],
         "4gpu": ["schedule.scaling=strong", "schedule.gpus=4"]}


def use(variant: str) -> None:
    trial = variant == "together"
    device.Submission.finished = together if trial else TURNS
    device.Submission.wait = wait_for_waiters if trial else _WAIT


if __name__ == "__main__":
    root, pairs = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 6
    df = alternate(root, pairs, CASES, ("turns", "together"), use)
    print(df.groupby(["case", "variant"])[["frame_ms", "seen_us", "start_us"]].median().round(3))
