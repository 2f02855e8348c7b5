"""Executing the planned nodes: a submit thread and a reap thread per VkQueue, a host dispatcher
and K memcpy threads; trace rows on the host clock.

Why threads per queue: each stream must submit in its own order while waiting (on the host) for
producers on other devices, as the reference renderer's per-GPU threads do; cffi releases the
GIL during fence waits and submits, and numpy during copies, so they really overlap. The reap
thread reads every submission's timestamps in order and recycles its command buffer, fence and
semaphores; a thread waiting for a task only waits on its fence (`Submission.finished`), because
on lavapipe reading the timestamps blocks until the queue is idle. Any error in any thread stops
them all and is raised from `execute`.
"""
from __future__ import annotations

import os
import queue as queue_mod
import sys
import threading
import time
from collections import defaultdict
from typing import Any, Callable

import numpy as np

from mgpusim.model.errors import InputError, ScheduleError
from mgpusim.real.host import priority as host_priority
from mgpusim.real.runner.latch import Latch
from mgpusim.real.runner.plan import CPU_STREAM, HOST_STREAM, Node
from mgpusim.real.runner.work import CpuWork, GpuWork, HostWork
from mgpusim.real.vulkan.device import Gpu
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.skipping import SkipChains

POLL_S = 0.05


#: GIL switch interval during a run unless MGPUSIM_SWITCH_INTERVAL_S says otherwise. Python's
#: 5 ms default made hand-offs between runner threads take milliseconds (measured on the H200s:
#: 5.2 ms median wake-up with busy threads, 0.35 ms at 0.2 ms).
DEFAULT_SWITCH_INTERVAL_S = 0.0002


def switch_interval() -> float:
    """The interpreter's GIL switch interval during a run, from MGPUSIM_SWITCH_INTERVAL_S
    (default DEFAULT_SWITCH_INTERVAL_S). A thread woken by a fence or a finished host copy must
    get the GIL back before it can submit the next task; while other runner threads run Python
    (command recording), that can take up to one switch interval."""
    raw = os.environ.get("MGPUSIM_SWITCH_INTERVAL_S")
    if not raw:
        return DEFAULT_SWITCH_INTERVAL_S
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise InputError(f"MGPUSIM_SWITCH_INTERVAL_S must be > 0, got {raw!r}", field="MGPUSIM_SWITCH_INTERVAL_S")
    return value


def _nothing() -> None:
    """What a started-and-joined thread of the as-built host loop does: its start is the cost."""


class _Abort(Exception):
    """Another thread failed; this one stops quietly."""


class Executor:
    """Runs `nodes` once; `rows` are trace tuples (TRACE_COLUMNS order, absolute host ns),
    `submissions` the host side of each GPU task and host copy (SUBMISSION_COLUMNS order,
    absolute host ns).

    Skippable tasks (`skip_if_busy`, the particle demo's "new wait") follow the simulator's
    rule (:class:`mgpusim.schedules.skipping.SkipChains`), decided when the task's stream reaches it
    with its dependencies met (the CPU's submit time): a skipped instance records nothing, has
    no trace row, counts as finished at once for its consumers, and is listed in
    `skipped_frames`, as the simulator lists it. `newest` and `skipped_before` answer the
    per-submission questions of works that depend on the run's course (GpuWork.choose)."""

    def __init__(self, nodes: list[Node], host_threads: int, stall_timeout_s: float,
                 program: FrameProgram):
        self.nodes, self.host_threads, self.stall_s = nodes, host_threads, stall_timeout_s
        self.abort = threading.Event()
        self.errors: list[BaseException] = []
        self.rows: list[tuple] = []
        self.submissions: list[tuple] = []
        self._rows_lock = threading.Lock()
        self._sem_pool: dict[int, list[Any]] = defaultdict(list)
        self._sem_lock = threading.Lock()
        #: the memcpy threads' parts to copy (a SimpleQueue: put and get are C, no Python lock)
        self._parts: queue_mod.SimpleQueue = queue_mod.SimpleQueue()
        #: the threads host copies started of their own (`HostCopyTask.own_threads`), joined last
        self._own_threads: list[threading.Thread] = []
        self._by_key = {(n.frame, n.task.name): n for n in nodes}
        self._skip_lock = threading.Lock()
        #: skippable GPU nodes submitted and not yet known to be finished (see `_skipped`), by id
        self._running_skippable: dict[int, Node] = {}
        self._chains = None
        if any(t.skip_if_busy for tasks in program.templates for t in tasks):
            self._chains = SkipChains(program, [{t.name: t for t in tasks}
                                                for tasks in program.templates])
        #: per reading task, the frame whose output each frame's instance read (`newest`)
        self.read_frames: dict[str, dict[int, int | None]] = defaultdict(dict)
        #: with MGPUSIM_HOST_PRIORITY=realtime on lavapipe, the runner's threads take
        #: SCHED_FIFO as lavapipe's do (host/priority.py)
        self.promote_threads = host_priority.wanted() and any(
            isinstance(n.work, GpuWork) and n.work.gpu.info.is_lavapipe for n in nodes)

    @property
    def skipped_frames(self) -> dict[str, list[int]]:
        return dict(self._chains.skipped_frames) if self._chains is not None else {}

    # -- skipping and run-time choices ---------------------------------------------------------
    def _skipped(self, node: Node) -> bool:
        """Decide now whether `node` (dependencies met) is skipped; a skipped node is done.

        Whether a chain is still busy is whether its work is still running *now*: its GPU
        nodes that finished are marked so first (a non-blocking look at their fences). Their
        reap thread alone would tell too late: it reads each submission's timestamps in queue
        order, and on lavapipe that read waits for the queue to go idle, so on a busy primary
        it lagged frames behind and every later update was skipped (3 updates in 57 frames)."""
        if self._chains is None or not node.task.skip_if_busy:
            return False
        self._mark_finished_skippables()
        key = (node.frame, node.task.name)
        with self._skip_lock:
            self._chains.ready(key, node.task)
            skipped = key in self._chains.skip
            self._chains.skip.discard(key)
        if skipped:
            node.skipped = True
            self._done(node)
        return skipped

    def _mark_finished_skippables(self) -> None:
        """Every running skippable GPU node whose fence has signalled is done."""
        with self._skip_lock:
            running = list(self._running_skippable.values())
        for other in running:
            if other.submission is not None and other.submission.poll():
                self._done(other)

    def _done(self, node: Node) -> None:
        """`node` finished (or was skipped): wake its waiters, tell the skip chains once. Only
        a skippable task's end needs the lock (the chains are shared state); setting an event
        twice is harmless, so every other completion stays lock-free."""
        if self._chains is None or not node.task.skip_if_busy:
            node.completed.set()
            return
        with self._skip_lock:
            self._running_skippable.pop(id(node), None)
            if node.completed.is_set():
                return
            node.completed.set()
            if not node.skipped:
                self._chains.finished(node.frame, node.task)

    def skipped_before(self, name: str, frame: int) -> int:
        """How many instances of task `name` right before `frame` were skipped."""
        count = 0
        node = self._by_key.get((frame - 1, name))
        while node is not None and node.skipped:
            count += 1
            node = self._by_key.get((node.frame - 1, name))
        return count

    def newest(self, writer: str, frame: int, queue: Any, reader: str) -> int | None:
        """The newest frame <= `frame` whose instance of `writer` ran and has finished, or was
        submitted to `queue` (which then runs it before the reader): what a reader that does not
        wait for `writer` may safely read. Recorded in `read_frames[reader]`."""
        found = None
        for g in range(frame, -1, -1):
            node = self._by_key.get((g, writer))
            if node is None or node.skipped:
                continue
            same_queue = isinstance(node.work, GpuWork) and node.work.queue is queue
            if node.completed.is_set() or (same_queue and node.submitted.is_set()):
                found = g
                break
        self.read_frames[reader][frame] = found
        return found

    # -- waiting ---------------------------------------------------------------------------
    def _wait(self, event: Latch, who: Node, what: str) -> None:
        deadline = time.monotonic() + self.stall_s
        while not event.wait(POLL_S):
            if self.abort.is_set():
                raise _Abort()
            if time.monotonic() > deadline:
                raise ScheduleError(f"{who.label} waited {self.stall_s:.0f} s for {what}: the "
                                    f"schedule is stuck (blocked dependency)")

    def _finish(self, node: Node, waiter: Node) -> None:
        """Block until `node` completed: the end of its GPU work, or of a host copy. Several
        threads may wait for one node."""
        if not isinstance(node.work, GpuWork):  # a host copy or a CPU task
            self._wait(node.completed, waiter, f"{node.label} to finish")
            return
        self._wait(node.submitted, waiter, f"{node.label} to be submitted")
        deadline = time.monotonic() + self.stall_s
        while not node.completed.is_set():
            if node.submission.finished(int(POLL_S * 1e9)):
                self._done(node)
            elif self.abort.is_set():
                raise _Abort()
            elif time.monotonic() > deadline:
                raise ScheduleError(f"{node.label} did not finish on the device within "
                                    f"{self.stall_s:.0f} s")

    # -- semaphores --------------------------------------------------------------------------
    def _semaphore(self, gpu: Gpu) -> Any:
        with self._sem_lock:
            pool = self._sem_pool[id(gpu)]
            return pool.pop() if pool else gpu.semaphore()

    def _release(self, node: Node) -> None:
        with self._sem_lock:
            for sem in node.waits:
                self._sem_pool[id(sem.gpu)].append(sem)
        node.waits = []

    # -- threads ---------------------------------------------------------------------------
    def _guard(self, fn: Callable[..., None], *args: Any) -> None:
        if self.promote_threads:
            host_priority.promote()
        try:
            fn(*args)
        except _Abort:
            pass
        except BaseException as exc:  # noqa: BLE001 - handed to the caller of execute()
            self.errors.append(exc)
            self.abort.set()

    def _submit_stream(self, nodes: list[Node]) -> None:
        for node in nodes:
            work = node.work
            assert isinstance(work, GpuWork)
            for prod, kind in node.deps:
                if kind == "host":
                    self._finish(prod, node)
                elif kind == "semaphore":
                    self._wait(prod.submitted, node, f"{prod.label} to be submitted")
                    if not prod.skipped:
                        node.waits.append(prod.signals.pop(id(node)))
            seen = time.monotonic_ns()
            if self.abort.is_set():
                raise _Abort()
            if self._skipped(node):
                if node.waits:  # consume the semaphores it was signalled, so they can be reused
                    node.submission = work.gpu.submit(work.queue, lambda cmd: None, wait=node.waits,
                                                      label=f"{node.label} (skipped)",
                                                      key=("skipped", id(work)))
                node.submitted.set()
                continue
            for cons in node.sem_consumers:
                node.signals[id(cons)] = self._semaphore(work.gpu)
            frame = node.frame
            choice = work.choose(frame, self) if work.choose is not None else None
            call = time.monotonic_ns()
            node.submission = work.gpu.submit(
                work.queue, work.bound(frame, choice),
                wait=node.waits, signal=list(node.signals.values()), label=node.label,
                key=work.key(frame, choice))
            with self._rows_lock:
                self.submissions.append((frame, f"gpu{work.device}", work.engine, node.task.name,
                                         seen, call, time.monotonic_ns()))
            if node.task.skip_if_busy and self._chains is not None:
                with self._skip_lock:
                    if not node.completed.is_set():
                        self._running_skippable[id(node)] = node
            node.submitted.set()

    def _reap_stream(self, nodes: list[Node]) -> None:
        for node in nodes:
            self._wait(node.submitted, node, f"{node.label} to be submitted")
            if node.skipped:  # decided before `submitted` was set
                self._reap_skipped(node)
                continue
            self._finish(node, node)
            span = node.submission.timestamps_ns()  # also recycles the command buffer
            self._release(node)
            work = node.work
            assert isinstance(work, GpuWork)
            row = (node.frame, f"gpu{work.device}", work.engine, node.task.step, node.task.name,
                   span[0], span[1], work.nbytes, node.waits_for)
            with self._rows_lock:
                self.rows.append(row)

    def _reap_skipped(self, node: Node) -> None:
        """A skipped node leaves no row; its semaphore-draining submission is recycled."""
        sub = node.submission
        if sub is None:
            return
        while not sub.finished(int(POLL_S * 1e9)):
            if self.abort.is_set():
                raise _Abort()
        sub.timestamps_ns()
        self._release(node)

    def _host_dispatch(self, nodes: list[Node]) -> None:
        """The host copies in order: each, once its inputs finished, split into parts for the
        memcpy threads. Its submissions row (device `host`, engine `memcpy`) says when the
        dispatcher saw the inputs, began queueing the parts and had queued them all, so that a
        copy's hand-off splits as a GPU task's does (`results.waits.host_split`)."""
        for node in nodes:
            for prod, _kind in node.deps:
                self._finish(prod, node)
            seen = time.monotonic_ns()
            if self._skipped(node):
                node.submitted.set()
                continue
            assert isinstance(node.work, HostWork)
            parts = node.work.parts(node.frame)
            node.parts_left = len(parts)
            node.submitted.set()
            call = time.monotonic_ns()
            if node.work.task.own_threads:  # a new thread per part, as parallelCopy starts them
                for k, (dst, src) in enumerate(parts):
                    part = threading.Thread(target=self._guard, args=(self._copy_part, node, dst, src,
                                                                      f"{node.task.name}.thread{k}"),
                                            name=f"{node.task.name}-part{k}")
                    part.start()
                    self._own_threads.append(part)
            else:
                for dst, src in parts:
                    self._parts.put((node, dst, src))
            with self._rows_lock:
                self.submissions.append((node.frame, "host", "memcpy", node.task.name, seen, call,
                                         time.monotonic_ns()))
        for _ in range(self.host_threads):
            self._parts.put(None)

    def _cpu_stream(self, nodes: list[Node]) -> None:
        """An application thread running its CPU tasks in order: each waits for its inputs
        (a GPU input: its fence, as vkQueueWaitIdle), then starts and joins its threads."""
        for node in nodes:
            for prod, _kind in node.deps:
                self._finish(prod, node)
            work = node.work
            assert isinstance(work, CpuWork)
            start = time.monotonic_ns()
            started = [threading.Thread(target=_nothing, name=f"{work.thread}-task{i}")
                       for i in range(work.threads)]
            for t in started:
                t.start()
            for t in started:
                t.join()
            end = time.monotonic_ns()
            with self._rows_lock:
                self.rows.append((node.frame, "host", work.thread, node.task.step, node.task.name,
                                  start, end, 0, node.waits_for))
            node.submitted.set()
            self._done(node)

    def _host_worker(self, k: int) -> None:
        while True:
            try:
                item = self._parts.get(timeout=POLL_S)
            except queue_mod.Empty:
                if self.abort.is_set():
                    return
                continue
            if item is None:
                return
            node, dst, src = item
            self._copy_part(node, dst, src, f"thread{k}")

    def _copy_part(self, node: Node, dst: np.ndarray, src: np.ndarray, thread: str) -> None:
        """One part of a host copy on `thread` (the trace's engine); the last part done ends
        the copy."""
        start = time.monotonic_ns()
        np.copyto(dst, src)
        end = time.monotonic_ns()
        with self._rows_lock:
            self.rows.append((node.frame, "host", thread, node.task.step, node.task.name,
                              start, end, int(dst.size), node.waits_for))
            node.parts_left -= 1
            last = node.parts_left == 0
        if last:
            self._done(node)

    def execute(self) -> list[tuple]:
        """Run every node; raise the first error any thread hit."""
        streams: dict[str, list[Node]] = defaultdict(list)
        for node in self.nodes:
            streams[node.stream].append(node)
        threads = []
        for name, nodes in streams.items():
            if name.startswith(CPU_STREAM):
                threads.append(threading.Thread(target=self._guard, args=(self._cpu_stream, nodes),
                                                name=name))
            elif name == HOST_STREAM:
                threads.append(threading.Thread(target=self._guard, args=(self._host_dispatch, nodes),
                                                name="host-dispatch"))
                threads += [threading.Thread(target=self._guard, args=(self._host_worker, k),
                                             name=f"memcpy{k}") for k in range(self.host_threads)]
            else:
                threads.append(threading.Thread(target=self._guard, args=(self._submit_stream, nodes),
                                                name=f"submit-{name}"))
                threads.append(threading.Thread(target=self._guard, args=(self._reap_stream, nodes),
                                                name=f"reap-{name}"))
        interval = switch_interval()
        old = sys.getswitchinterval()
        sys.setswitchinterval(interval)
        try:
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            for t in self._own_threads:  # (done by now: every copy has a task that waits on it)
                t.join()
        finally:
            sys.setswitchinterval(old)
        if self.errors:
            raise self.errors[0]
        return self.rows
