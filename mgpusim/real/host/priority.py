"""An opt-in real-time policy for lavapipe's threads and the runner's (MGPUSIM_HOST_PRIORITY).

A lavapipe GPU is threads on the host's cores: its rasterizers (``llvmpipe-N``, which also
write its timestamps) and a queue thread that executes the command buffers, driven by the
runner's submit, reap and memcpy threads. Under the normal policy on our 2-core VM (EEVDF, a
250 Hz tick, and a kernel that packs woken threads onto a busy vCPU) a thread woken while
another GPU's rasterizers ran sometimes sat in that busy core's run queue until the next tick
while the other core went idle: `perf record -e sched:sched_switch -e sched:sched_wakeup` on a
4-GPU AFR run at 128x96 showed 4-6 ms waits in about 7 % of all hand-offs, and the frame took
5.0-5.5 ms where the model, which shares the cores as a fluid, says 4.3 ms.

``MGPUSIM_HOST_PRIORITY=realtime`` puts every thread lavapipe starts (while an instance or
device is created) and the runner's threads on SCHED_FIFO 1, where the kernel places a woken
thread on an idle core at once: that AFR run then takes 4.25-4.31 ms. It is not the default
because SCHED_FIFO does not time-slice: a long pass's rasterizers keep both cores until they
run out of work, so another GPU's copy can wait for all of it (33 ms behind a 41 ms pass in a
pipelining run), which the fluid model does not know either; over two full jobs the sort-last
and pipelining runs at 3x the calibrated size came out worse (docs/validation.md). The
interpreter's main thread keeps its policy (it later calibrates and simulates for minutes).
Where the system refuses the policy, the runs go on at the normal one and the machine record
says so.
"""
from __future__ import annotations

import os
import threading

from mgpusim.model.errors import InputError

ENV = "MGPUSIM_HOST_PRIORITY"
#: SCHED_FIFO priority of every promoted thread
PRIORITY = 1

_lock = threading.Lock()
_refused: list[str] = []
_promoted: list[bool] = []  # [True] once a thread was promoted


def wanted() -> bool:
    """Whether lavapipe's and the runner's threads get the real-time policy
    (MGPUSIM_HOST_PRIORITY: normal, the default, or realtime)."""
    raw = os.environ.get(ENV, "normal").strip().lower() or "normal"
    if raw not in ("realtime", "normal"):
        raise InputError(f"{ENV} must be 'realtime' or 'normal', got {raw!r}", field=ENV)
    return raw == "realtime"


def thread_ids() -> set[int]:
    """This process's threads (empty where /proc is not there)."""
    try:
        return {int(tid) for tid in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def promote(tid: int = 0) -> bool:
    """Put thread `tid` (0: the calling thread) on SCHED_FIFO; False where it was refused."""
    if not hasattr(os, "sched_setscheduler"):
        _refuse("no real-time scheduling on this system")
        return False
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except ProcessLookupError:  # the thread ended meanwhile
        return False
    except OSError as exc:
        _refuse(f"sched_setscheduler refused: {exc.strerror or exc}")
        return False
    with _lock:
        _promoted[:] = [True]
    return True


def _refuse(reason: str) -> None:
    with _lock:
        if not _refused:
            _refused.append(reason)


def snapshot() -> set[int] | None:
    """The process's threads before the driver starts some (None: promotion is off)."""
    return thread_ids() if wanted() else None


def promote_new(before: set[int] | None) -> None:
    """Promote the threads started since `before` (a :func:`snapshot`): call it after creating
    a lavapipe instance or device (Mesa 22.3 starts them all in vkCreateDevice: the queue
    thread, the rasterizers and the compute-shader pool). Threads the driver put in the
    background itself (SCHED_BATCH, SCHED_IDLE: its shader-cache writer) stay there."""
    if before is None:
        return
    for tid in thread_ids() - before:
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                continue
        except OSError:  # the thread ended meanwhile
            continue
        promote(tid)


def status() -> str:
    """For the machine record: the policy lavapipe's and the runner's threads ran under."""
    if not wanted():
        return "normal"
    with _lock:
        if _refused:
            return f"normal ({_refused[0]})"
        return "realtime (SCHED_FIFO 1)" if _promoted else "normal (no lavapipe threads)"
