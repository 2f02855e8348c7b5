"""Fence waits in turn (under the submission's lock) against all at once, on XR strong scaling.

`Submission.finished` holds the submission's lock while inside vkWaitForFences, so the threads
awaiting one task's end (its reaper and each consumer on another queue) wake one after another.
The trial version (`together`, below) let them wait on the fence at once, counting the waiters
so that `wait()` resets the fence only once none is left. This runs `experiments/lavapipe/xr.toml` under strong scaling on
2 and 4 lavapipe GPUs (8 rasterizer threads each), alternating run by run between `turns` (the
runner's method) and `together` (patched in from outside), and writes per
run: frame time, and the median hand-off split of the renders bound by another GPU's task (us
from that task's end: `seen` until the submit thread had seen all inputs, `start` until the
render started).

    .venv/bin/python data/lavapipe/fence_wait_2026-11-26/ab_probe.py OUT [PAIRS]

A record of one experiment, not part of the package.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

import mgpusim.vulkan.device as device
from mgpusim.cli import main
from mgpusim.waits import _ready_rows

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
            pass
    return _WAIT(self, timeout_ns)


def split(folder: Path) -> dict[str, float]:
    trace, subs = pd.read_csv(folder / "trace.csv"), pd.read_csv(folder / "submissions.csv")
    rows = _ready_rows(trace, 1)
    rows = rows[(rows.binding != "queue") & (rows.step == "render")]
    rows = rows.merge(subs[["frame", "task", "inputs_seen_ns"]], on=["frame", "task"])
    summary = json.loads((folder / "summary.json").read_text())
    return {"frame_ms": summary["frame_time_ms"], "handoffs": len(rows),
            "seen_us": float((rows.inputs_seen_ns - rows.ready_ns).median() / 1e3),
            "start_us": float((rows.start_ns - rows.ready_ns).median() / 1e3)}


def run(out: Path, gpus: int, variant: str) -> dict[str, float]:
    trial = variant == "together"
    device.Submission.finished = together if trial else TURNS
    device.Submission.wait = wait_for_waiters if trial else _WAIT
    sets = ["schedule.scaling=strong", f"schedule.gpus={gpus}", "schedule.frames=60"]
    rc = main(["run", "experiments/lavapipe/xr.toml", *[a for s in sets for a in ("--set", s)],
               "--lp-threads", "8", "--out", str(out)])
    assert rc == 0, rc
    return split(out)


if __name__ == "__main__":
    root, pairs = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 6
    rows = []
    for i in range(pairs):
        for gpus in (2, 4):
            order = ("turns", "together") if i % 2 == 0 else ("together", "turns")
            for variant in order:
                r = run(root / f"{gpus}gpu_{i}_{variant}", gpus, variant)
                rows.append({"pair": i, "gpus": gpus, "variant": variant, **r})
    df = pd.DataFrame(rows)
    df.to_csv(root / "ab.csv", index=False)
    print(df.groupby(["gpus", "variant"])[["frame_ms", "seen_us", "start_us"]].median().round(3))
