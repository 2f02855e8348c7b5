"""The SimPy executor: runs a FrameProgram on modelled queues, links and host threads.

- Each queue is one process that runs its tasks in submission order, one at a time, waiting
  for each task's dependencies first (a Vulkan queue with semaphore waits behaves so).
- Copies hold their queue and cross a fluid :class:`Channel` (PCIe direction, peer link).
- Host copies are dispatched in order by the host thread, split into parts of at least
  `chunk_min_bytes` over the memcpy thread pool, each part a flow on host memory bandwidth
  capped at one thread's speed.
- Devices run their work on the executors the engine is given (:mod:`.executors`): their own
  cores, or a pool shared with other devices (CPU-emulated GPUs); the engine asks each executor
  for a runner once per task and never branches on its kind in the hot loop.
- What each task costs, which channel it crosses and how its row is labelled is decided once
  per task, before the run, by :class:`.ops.OpBuilder` (shared with the analytic level and the
  replay); the engine runs the timeline of those ops.
- Only the effects a scene calls for are instantiated (:mod:`.effects`).
Dependencies are counted, not stored as events per task, so memory stays flat over 10^5 frames.
"""
from __future__ import annotations

import contextlib
import heapq
from array import array
from collections import defaultdict, deque
from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING, Callable, Iterable, Mapping

import numpy as np
import simpy

from mgpusim.model.costs import CostModel, gbps_fraction, round_half_up
from mgpusim.model.errors import InputError, ScheduleError
from mgpusim.model.geometry import even_split
from mgpusim.model.limits import INT64_MAX
from mgpusim.model.profile_reads import not_reading
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, QueueRef, Task
from mgpusim.schedules.base import FrameProgram, leads_chain, wakes_host
from mgpusim.schedules.skipping import GivenSkips, SkipChains
from mgpusim.schedules.task_inputs import TaskInputs
from mgpusim.sim.busy_wake import BusyWake
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.executors import Executor, make_executors
from mgpusim.sim.ops import Key, Op, OpBuilder, RunChannel
from mgpusim.sim.snapshot import Callback, Environment, Relative, StreamProcess

if TYPE_CHECKING:
    from mgpusim.results.periodic import RowColumns

_heappop, _heappush = heapq.heappop, heapq.heappush  # (looked up once: used per host-copy part)


class _Stream:
    """Where one in-order stream stands, written down as it runs so that its state can be read
    without looking into its generator: the frame and task it is at, what it waits for there
    (`at`, one of the labels below), and the values still to be used from that point on."""

    __slots__ = ("host", "frame", "op", "at", "submitted", "start", "wait", "target")

    def __init__(self, host: bool):
        self.host = host
        self.frame, self.at = 0, "start"
        self.op: Op | None = None
        self.submitted = self.start = self.wait = 0
        #: the event a stream that waits by itself waits on (None: its process's target)
        self.target: simpy.Event | None = None


#: Where a stream waits (`_Stream.at`): its task's dependencies; the host-copy thread's wake-up;
#: its turn at the interpreter and its dispatch work (`wait` still to use); its submit thread;
#: the queue's idle gap; a copy's thread behind a core-filling pass; its work and its transfer
#: (`start` still to use).
DEPS, COPY_WAKE, TURN, DISPATCH, SUBMIT, GAP, BUSY_WAKE, RUN, TRANSFER = (
    "deps", "copy wake", "turn", "dispatch", "submit", "gap", "busy wake", "run", "transfer")


@dataclass
class RawResult:
    """What the engine observed; :mod:`mgpusim.results.summary` turns it into tables."""

    rows: list[tuple] | RowColumns  # (columns: the analytic level's filled-in frames)
    frame_start: np.ndarray
    present_end: np.ndarray
    channels: dict[str, RunChannel]
    skipped: dict[str, int] = field(default_factory=dict)
    #: what the run showed of the effects (link contention, ...); the analytic level says
    #: whether it is exact and, where not, lists its approximations
    effects: dict[str, bool | list[str]] = field(default_factory=dict)
    #: frames in which each skippable task was skipped (for update rates in steady state)
    skipped_frames: dict[str, list[int]] = field(default_factory=dict)
    present_task: str = "present"
    #: the ids in the rows' last column, and the inputs each lists (None: the rows carry text)
    inputs: TaskInputs | None = None
    #: whether `rows` holds the trace the caller asked for (else it is empty or internal)
    recorded: bool = True
    #: set by a fast-forward: how the logs repeat (mgpusim.sim.fastforward.Repeat)
    repeat: object = None
    fast_forward: dict = field(default_factory=dict)
    #: `frame_start` and `present_end` already cover every frame of the run, repeats included
    #: (the analytic level extends them itself; else they are built from the rows)
    frames_whole: bool = False


class Engine:
    """The event model of one program: a process per stream running its ops (built once by
    :class:`.ops.OpBuilder`), the dependency counts between task instances, the host's threads,
    and what the run observed (:meth:`run`)."""

    def __init__(self, program: FrameProgram, costs: CostModel, record_trace: bool = True,
                 effects: frozenset[str] | None = None,
                 executors: Callable[[simpy.Environment], dict[str, Executor]] | None = None,
                 durations: Mapping[Key, int] | None = None, skips: Iterable[Key] | None = None):
        """`effects`: the effects to instantiate (default: those the scene needs, see
        :func:`.effects.choose_effects`). `executors`: builds the executor of every device and
        the host (default: shared host cores where the shared_executor effect is on).
        `durations`: (phase, task name) -> ns the task takes there instead of its cost (the
        replay level, :mod:`.replay`: measured durations, which the builder makes measured ops
        of, :meth:`.ops.OpBuilder.measured_op`; a copy then crosses no channel, a host copy's
        every part takes the given time). `skips`: the (frame, task) instances to
        skip instead of the skip rule's decisions (the replay: those a measured run skipped)."""
        self.program, self.costs, self.record = program, costs, record_trace
        if effects is None:
            effects = choose_effects(program, costs.profile)
        self.effects = effects
        self.env = Environment()
        #: frames the streams run (a fast-forward may shorten it while running)
        self.horizon = program.frames
        self.rows: list[tuple] = []
        self.period = len(program.templates)
        # int64 arrays the hot path reads as Python ints (a numpy scalar costs more than the rest)
        self.frame_start = array("q", [INT64_MAX]) * program.frames
        self.present_end = array("q", [-1]) * program.frames
        self._pending: dict[Key, int] = {}
        self._waiters: dict[Key, simpy.Event] = {}
        self._ready: set[Key] = set()
        self._index = [{t.name: t for t in tasks} for tasks in program.templates]
        self._chains: SkipChains | GivenSkips = (SkipChains(program, self._index) if skips is None
                                                 else GivenSkips(skips))
        self._skip = self._chains.skip  # instances marked to be skipped, read in the hot loop
        host = costs.profile.host
        submission = "host_submission" in effects
        self._dispatch_ns = host.dispatch_ns if submission else 0
        self._copy_wake_ns = host.host_copy_wake_ns if submission else 0
        self._submit_ns = host.submit_ns if submission else 0
        self._host_timeline = bool(self._dispatch_ns or self._submit_ns or self._copy_wake_ns)
        self._dependents = self._reverse_deps()
        self._cross_done: dict[Key, int] = {}  # instance -> when its last cross-device input ended
        self._busy_wake = (BusyWake(host.busy_wake_share, host.busy_wake_ns,
                                    host.busy_wake_window_ns, host.cpu_cores)
                           if "busy_wake" in effects else None)
        self._unfinished = self._tasks_in(0, program.frames)
        self.processes: list[StreamProcess] = []
        self.streams: list[_Stream] = []  # the processes' positions, in the same order
        #: called with the frame number when a frame presents (the fast-forward's probe)
        self.on_present: Callable[[int], None] | None = None
        #: vsync: the display's refresh period in ns (exact), and the last flip's time
        self.refresh_period = (Fraction(10 ** 9) / gbps_fraction(program.refresh_hz)
                               if program.refresh_hz else None)
        self._last_flip = -1
        self._setup_resources(executors or (
            lambda env: make_executors(env, costs, "shared_executor" in effects,
                                       program if "shared_gpu" in effects else None)), durations)

    # ----- build -------------------------------------------------------------------------
    def _reverse_deps(self) -> list[dict[str, list[tuple[str, int, Task, int, int, bool, bool]]]]:
        """dependents[phase][name] = [(dependent, frame distance k >= 0, its task, its number
        of dependencies, the frame from which all of them exist, whether the edge crosses
        devices or the host where the host timeline is modelled: a host thread must wake to act
        on it, whether the dependent is skippable)]."""
        out: list[dict[str, list]] = [defaultdict(list) for _ in range(self.period)]
        for q, tasks in enumerate(self.program.templates):
            for task in tasks:
                lag = max((-d.offset for d in task.deps), default=0)
                for dep in task.deps:
                    k = -dep.offset
                    producer = self._index[(q - k) % self.period][dep.task]
                    cross = self._host_timeline and wakes_host(producer, task, leads_chain(task, self._index[q]))
                    out[(q - k) % self.period][dep.task].append(
                        (task.name, k, task, len(task.deps), lag, cross, task.skip_if_busy))
        return out

    def _setup_resources(self, executors: Callable[[Environment], dict[str, Executor]],
                         durations: Mapping[Key, int] | None) -> None:
        """The executors, the ops (:class:`.ops.OpBuilder`: durations, channels, labels), the
        host threads' state, and a process per stream with the ops it runs per frame phase."""
        self.executors = executors(self.env)
        self.builder = OpBuilder(self.program, self.costs, self.effects, self.env, self.executors,
                                 durations, self._busy_wake)
        #: every task's id and the inputs its trace row lists; rows log the id
        self.inputs = self.builder.inputs
        #: every channel of the run, in the order made (the builder's: it adds the links)
        self.channels = self.builder.channels
        host_ex = self.executors["host"]
        self._host_work = host_ex.work  # one host thread's ns of time
        serial = self.costs.profile.host.serial_dispatch  # the profile's word, else the executor's
        self._serial_dispatch = host_ex.serial_dispatch if serial is None else serial
        self._interp_busy = False  # a host thread is waking (serial dispatch)
        self._interp_waiting: deque[simpy.Event] = deque()  # threads waiting for their turn
        self._submit_load = host_ex.background() if self._submit_ns else None
        queues: dict[QueueRef | tuple[str, str], list[list[Op]]] = {}  # a queue, or ("host", a CPU thread)
        host_ops: list[list[Op]] = [[] for _ in range(self.period)]
        self._ops = self.builder.all_ops()
        for phase, ops in enumerate(self._ops):
            for op in ops:
                task = op.task
                object.__setattr__(op, "dependents", self._dependents[phase].get(task.name, []))
                if isinstance(task, HostCopyTask):
                    host_ops[phase].append(op)
                else:
                    stream = ("host", task.thread) if isinstance(task, CpuTask) else task.queue
                    queues.setdefault(stream, [[] for _ in range(self.period)])[phase].append(op)
        for plan in queues.values():
            self._start_stream(plan, host=False)
        if any(host_ops):
            host = self.costs.profile.host
            self._threads_all = [f"thread{i}" for i in range(host.memcpy_threads)]
            self._part_sizes: dict[Op, list[int]] = {}  # a host copy's part sizes, per task
            self._free_threads = list(range(host.memcpy_threads))
            self._part_queue: deque = deque()
            #: a thread start, before each part of a copy on threads of its own (host_frame_work)
            self._part_thread_ns = host.thread_start_ns if "host_frame_work" in self.effects else 0
            # where memcpys are core work the channel is only reported: its rate is unused
            with not_reading() if host_ex.copies_on_cores else contextlib.nullcontext():
                memory = self.builder.host_memory()
            # a part runs at its copy's cap (its op's): a memcpy thread's speed, or slower
            # where it reads uncached memory (the uncached_reads effect)
            if host_ex.copies_on_cores:  # a memcpy thread is one core's work
                self._part_event = lambda size, cap: host_ex.work(-(-size * cap.denominator // cap.numerator))
            else:
                self._part_event = memory.transfer
            self._start_stream(host_ops, host=True)

    def _start_stream(self, plan: list[list[Op]], host: bool) -> None:
        stream = _Stream(host)
        self.streams.append(stream)
        box: list[StreamProcess] = []  # a lean generator's process, read once it runs
        if host and not self._host_timeline:
            proc = self._lean_stream_proc(plan, stream, box, host=True)
        elif (not host and not self._host_timeline and self._busy_wake is None
              and not any(op.gap for ops in plan for op in ops)):  # (fill_cores needs busy_wake)
            proc = self._lean_stream_proc(plan, stream, box)
        else:
            proc = self._stream_proc(plan, stream, box)
        box.append(StreamProcess(self.env, proc))
        self.processes.append(box[0])

    def _dispatch_wait(self, key: Key, keep: bool = False) -> int:
        """Host dispatch still owed before `key` starts: `dispatch_ns` after the last of its
        inputs from another device or the host finished (0 if that is long past). `keep`: leave
        the input's end for :meth:`_submitted`."""
        done = self._cross_done.get(key) if keep else self._cross_done.pop(key, None)
        if done is None:
            return 0
        return max(0, done + self._dispatch_ns - self.env.now)

    def _copy_wake(self, key: Key) -> int:
        """When the host-copy thread, idle, is awake to dispatch `key`: `host_copy_wake_ns`
        after its last input from a device ended (0 without one). The dispatch work after it
        is owed from then (the input's end is moved there for :meth:`_dispatch_wait`)."""
        done = self._cross_done.get(key)
        if done is None:
            return 0
        woken = done + self._copy_wake_ns
        self._cross_done[key] = woken
        return woken

    def _interpreter_turn(self) -> simpy.Event | None:
        """A host thread about to wake on an input takes the interpreter: None if it is free
        (taken now) or the host's threads need no turns, else an event that fires when the
        threads before it are done (FIFO)."""
        if not self._serial_dispatch:
            return None
        if not self._interp_busy:
            self._interp_busy = True
            return None
        turn = self.env.event()
        self._interp_waiting.append(turn)
        return turn

    def _interpreter_done(self) -> None:
        """Hand the interpreter to the next waiting thread, or free it."""
        if not self._serial_dispatch:
            return
        if self._interp_waiting:
            self._interp_waiting.popleft().succeed()
        else:
            self._interp_busy = False

    def _submitted(self, key: Key, previous: int, woke: int = 0) -> int:
        """When the queue's submit thread has submitted `key`: `submit_ns` after the task
        before it, and after waking on its last input from another device or the host
        (`dispatch_ns` after that input ended, or at `woke` where waking was work on a shared
        executor that ended later)."""
        done = self._cross_done.pop(key, None)
        ready = previous if done is None else max(previous, done + self._dispatch_ns, woke)
        return ready + self._submit_ns

    # ----- dependencies ------------------------------------------------------------------
    def _initial(self, frame: int, task: Task) -> int:
        return sum(1 for d in task.deps if frame + d.offset >= 0)

    def _check_ready(self, key: Key, task: Task) -> bool:
        """True if `key` may start now; else the caller waits on a waiter event."""
        if key in self._ready:
            self._ready.discard(key)
            return True
        if key in self._pending:
            return False
        count = self._initial(key[0], task)
        if count == 0:
            self._chains.ready(key, task)
            return True
        self._pending[key] = count
        return False

    def _complete(self, frame: int, task: Task, skipped: bool = False,
                  dependents: list | None = None) -> None:
        """An instance is done: count it off its dependents' inputs; those with none left are
        ready (their waiting stream resumes, or finds them ready when it gets there).
        `dependents`: the task's entry of the dependents table, where the caller has it."""
        self._unfinished -= 1
        if not skipped and task.skip_if_busy:
            self._chains.finished(frame, task)
        if dependents is None:
            dependents = self._dependents[frame % self.period].get(task.name)
        if not dependents:
            return
        frames, pending, waiters = self.horizon, self._pending, self._waiters
        for name, k, dtask, ndeps, lag, cross, skippable in dependents:
            g = frame + k
            if g >= frames:
                continue
            key = (g, name)
            if cross:  # (only where the host timeline is modelled)
                self._cross_done[key] = self.env.now
            if g >= lag:  # all its inputs exist: count them down from ndeps (one lookup)
                left = pending.pop(key, ndeps) - 1
            else:
                left = pending.pop(key, None)
                left = (self._initial(g, dtask) if left is None else left) - 1
            if left:
                pending[key] = left
                continue
            if skippable:
                self._chains.ready(key, dtask)
            waiter = waiters.pop(key, None)
            if waiter is not None:
                self.env.trigger(waiter)
            else:
                self._ready.add(key)

    # ----- processes ---------------------------------------------------------------------
    def _stream_proc(self, plan: list[list[Op]], st: _Stream, proc: list[StreamProcess]):
        """One in-order stream: a queue, or (`st.host`) the host thread that dispatches host
        copies. Each task runs after its dependencies and any host dispatch it owes; a queue
        task then spends its pass or copy time and crosses its channel, a host copy is handed
        to the memcpy threads. Before each wait it writes in `st` where it stands. (One loop
        for both, inlined: this is the hot path.) It waits by itself, as
        :meth:`_lean_stream_proc` does (`resume` on the event, written down in `st.target`,
        then a bare yield). `proc`: [its process], filled before it runs."""
        env, period, skip, ready, host = self.env, self.period, self._skip, self._ready, st.host
        resume = proc[0].resume_direct
        cross_done, copy_wake, timeline = self._cross_done, self._copy_wake_ns, self._host_timeline
        busy_wake, finish = self._busy_wake, self._finish
        submitted = 0  # the queue's host submit thread: when it submitted the last task
        frame = 0
        while frame < self.horizon:
            st.frame = frame
            for op in plan[frame % period]:
                st.op = op
                key = (frame, op.task.name)
                if key in ready:  # the common case: dependencies already met
                    ready.discard(key)
                elif not self._check_ready(key, op.task):
                    ev = st.target = self._waiters[key] = env.event()
                    st.at = DEPS
                    ev.callbacks.append(resume)
                    yield
                if skip and key in skip:
                    self._skip_task(key, op.task)
                    continue
                # a host thread waking on the task's input from another device or the host:
                # the host-copy thread before it hands the copy to the memcpy threads, a queue's
                # submit thread before it submits (its own work on the host's executor: on
                # CPU-emulated GPUs it competes for the cores with the GPUs' passes)
                wait = 0
                if host and copy_wake and cross_done:
                    wait = self._copy_wake(key) - env.now
                    if wait > 0:  # the host-copy thread's wake latency (not CPU work)
                        st.at = COPY_WAKE
                        ev = st.target = env.timeout(wait)
                        ev.callbacks.append(resume)
                        yield
                    wait = 0
                if cross_done and (host or timeline):
                    wait = self._dispatch_wait(key, keep=not host)
                if wait:
                    st.wait = wait
                    turn = self._interpreter_turn()
                    if turn is not None:
                        st.at = TURN
                        st.target = turn
                        turn.callbacks.append(resume)
                        yield
                    st.at = DISPATCH
                    ev = st.target = self._host_work(wait)
                    ev.callbacks.append(resume)
                    yield
                    self._interpreter_done()
                if host:
                    self._dispatch_host_copy(frame, op)
                    continue
                if timeline:
                    # the queue's submit thread submits ahead of the queue, one task after
                    # another; a CPU task's thread itself wakes on its input and submits nothing
                    if op.cpu:
                        self._cross_done.pop(key, None)
                    else:
                        submitted = st.submitted = self._submitted(key, submitted, env.now if wait else 0)
                        if submitted > env.now:
                            st.at = SUBMIT
                            ev = st.target = env.timeout(submitted - env.now)
                            ev.callbacks.append(resume)
                            yield
                        if self._submit_load is not None:
                            self._submit_load(self._submit_ns)  # the submit thread's cores
                gap_run = op.gap_run  # (set where the task has a gap: one read either way)
                if gap_run is not None:
                    st.at = GAP
                    ev = st.target = gap_run(op.gap)
                    ev.callbacks.append(resume)
                    yield
                if busy_wake is not None and isinstance(op.task, CopyTask):
                    wait = busy_wake.copy_wait(op.device, env.now)
                    if wait:  # the copy's thread waits behind the pass; a core idles meanwhile
                        st.at = BUSY_WAKE
                        ev = st.target = self._host_work(wait)
                        ev.callbacks.append(resume)
                        yield
                start = st.start = env.now
                fills = op.fill_cores  # (set only where busy_wake is on)
                if fills is not None and busy_wake is not None:
                    busy_wake.pass_started(op.device, start, fills, op.duration)
                if op.run is not None:
                    st.at = RUN
                    ev = st.target = op.run(op.amount)
                    ev.callbacks.append(resume)
                    yield
                if fills is not None and busy_wake is not None:
                    busy_wake.pass_ended(op.device)
                if op.cross is not None:
                    st.at = TRANSFER
                    ev = st.target = op.cross()
                    ev.callbacks.append(resume)
                    yield
                finish(frame, op, op.engine, start, op.nbytes)
            frame += 1
        proc[0].finish()
        yield  # (never resumed)

    def _lean_stream_proc(self, plan: list[list[Op]], st: _Stream, proc: list[StreamProcess],
                          host: bool = False):
        """:meth:`_stream_proc` for a stream with nothing between its task's inputs and its
        work: no host timeline (dispatch, submit), no idle gaps, no busy_wake. The same steps
        in the same order, without the tests for what it lacks (the hot path of most runs).
        A queue runs each task and its transfer; the host-copy thread (`host`) hands each copy
        to the memcpy threads as soon as its inputs are met (no input's end is kept for a
        wake-up). It waits by itself (see StreamProcess: `resume` on the event, then a bare
        yield), and writes the event down in `st.target`. `proc`: [its process], filled before
        it runs."""
        env, period, skip, ready, pending = self.env, self.period, self._skip, self._ready, self._pending
        waiters, check_ready, complete = self._waiters, self._check_ready, self._complete
        frame_start, rows, resume = self.frame_start, self.rows, proc[0].resume_direct
        dispatch = self._dispatch_host_copy
        frame = 0
        while frame < self.horizon:
            st.frame = frame
            for op in plan[frame % period]:
                st.op = op
                key = (frame, op.name)
                if key in ready:  # the common case: dependencies already met
                    ready.discard(key)
                elif key in pending or not check_ready(key, op.task):  # (inputs counted: waits)
                    ev = st.target = waiters[key] = env.event()
                    st.at = DEPS
                    ev.callbacks.append(resume)
                    yield
                if skip and key in skip:
                    self._skip_task(key, op.task)
                    continue
                if host:
                    dispatch(frame, op)
                    continue
                start = st.start = env.now
                if op.run is not None:
                    st.at = RUN
                    ev = st.target = op.run(op.amount)
                    ev.callbacks.append(resume)
                    yield
                if op.cross is not None:
                    st.at = TRANSFER
                    ev = st.target = op.cross()
                    ev.callbacks.append(resume)
                    yield
                # _finish, inline
                if start < frame_start[frame]:
                    frame_start[frame] = start
                if self.record:
                    rows.append((frame, op.device, op.engine, op.task.step, op.name, start, env.now,
                                 op.nbytes, op.waits_for))
                if op.is_present:
                    self._finish_present(frame, op)
                else:
                    complete(frame, op.task, False, op.dependents)
            frame += 1
        proc[0].finish()
        yield  # (never resumed)

    def _skip_task(self, key: Key, task: Task) -> None:
        self._skip.discard(key)
        self._cross_done.pop(key, None)
        self._complete(key[0], task, skipped=True)

    def _finish(self, frame: int, op: Op, engine: str, start: int, nbytes: int) -> None:
        end = self.env.now
        if start < self.frame_start[frame]:
            self.frame_start[frame] = start
        if self.record:
            self.rows.append((frame, op.device, engine, op.task.step, op.task.name, start, end, nbytes,
                              op.waits_for))
        if not op.is_present:
            self._complete(frame, op.task, False, op.dependents)
        else:
            self._finish_present(frame, op)

    def _finish_present(self, frame: int, op: Op) -> None:
        """The present task ended now: the frame presents, or (vsync) is shown, and its
        present completes, at the next free refresh."""
        period = self.refresh_period
        if period is None:
            self._presented(frame, op)
            return
        end = self.env.now
        flip = self._next_vblank(end, period)
        self.env.timeout(flip - end).callbacks.append(_Presented(self, frame, op))

    def _presented(self, frame: int, op: Op) -> None:
        self.present_end[frame] = self.env.now
        if self.on_present is not None:
            self.on_present(frame)
        self._complete(frame, op.task, False, op.dependents)

    def _next_vblank(self, t: int, period: Fraction) -> int:
        """The first refresh at or after `t` and after the last flip (FIFO: one image per
        refresh). Refresh k is at k x `period` ns, rounded half up (exact for any rate)."""
        k = max(0, int(t // period) - 1)
        while (v := round_half_up(k * period)) < t or v <= self._last_flip:
            k += 1
        self._last_flip = v
        return v

    def _dispatch_host_copy(self, frame: int, op: Op) -> None:
        """Split into parts of >= chunk_min_bytes, at most one per memcpy thread; each part on
        a free thread of the pool (else queued for the first one free), or, for a copy that
        starts threads of its own, on a new thread: the copy's caller starts them one after
        another, `host.thread_start_ns` apart (host_frame_work), where there are several."""
        task: HostCopyTask = op.task  # type: ignore[assignment]
        sizes = self._part_sizes.get(op)
        if sizes is None:
            sizes = self._part_sizes[op] = even_split(task.bytes, task.parts(len(self._threads_all)))
        state = [len(sizes)]
        for k, size in enumerate(sizes):
            part = (frame, op, size, state)
            if task.own_threads:  # a thread of its own, named after the copy's part
                name = f"{task.name}.thread{k}"
                delay = task.part_start_ns(k, len(sizes), self._part_thread_ns)
                if delay:
                    self.env.timeout(delay).callbacks.append(_PartStart((self, name, part)))
                else:
                    self._start_part(name, part)
            elif self._free_threads:
                self._start_part(_heappop(self._free_threads), part)
            else:
                self._part_queue.append(part)

    def _start_part(self, tid: int | str, part: tuple) -> None:
        start = self.env.now
        op = part[1]
        if op.measured:  # its whole time, measured
            done = op.run(op.amount) if op.run is not None else self.env.timeout(0)
            done.callbacks.append(_PartDone((self, tid, part, start)))
        elif op.duration:  # the part's fixed cost, then its bytes
            self.env.timeout(op.duration).callbacks.append(_PartCopy((self, tid, part, start)))
        else:
            self._part_copy(tid, part, start)

    def _part_copy(self, tid: int | str, part: tuple, start: int) -> None:
        ev = self._part_event(part[2], part[1].cap)
        ev.callbacks.append(_PartDone((self, tid, part, start)))

    def _part_done(self, tid: int | str, part: tuple, start: int) -> None:
        """A part has crossed: its pool thread takes the next part waiting (a thread of the
        copy's own, named by a string, ends)."""
        frame, op, size, state = part
        if not isinstance(tid, str):
            if self._part_queue:
                self._start_part(tid, self._part_queue.popleft())
            else:
                _heappush(self._free_threads, tid)
        state[0] -= 1
        if start < self.frame_start[frame]:
            self.frame_start[frame] = start
        if self.record:
            self.rows.append((frame, "host", tid if isinstance(tid, str) else self._threads_all[tid],
                              op.task.step, op.task.name, start,
                              self.env.now, size, op.waits_for))
        if state[0] == 0:
            self._complete(frame, op.task, False, op.dependents)

    # ----- state (for the fast-forward) ------------------------------------------------------
    @property
    def skipped_frames(self) -> dict[str, list[int]]:
        """Frames in which each skippable task was skipped, so far."""
        return self._chains.skipped_frames

    def cheap_state(self) -> tuple:
        """A part of the state that is quick to take: how many instances wait on what."""
        return (len(self._pending), len(self._ready), len(self._cross_done), len(self._skip))

    def named_events(self, rel: Relative) -> list[tuple[tuple, simpy.Event]]:
        """The events the engine and its channels hold and will trigger, each with a name that
        says what it stands for: a transfer's end, an instance's dependencies met, a host
        thread's turn at the interpreter."""
        out: list[tuple[tuple, simpy.Event]] = []
        for name, ch in self.channels.items():
            out.extend((("flow", name, j), ev) for j, ev in enumerate(ch.flow_events()))
        out.extend((("wait", rel.key(k)), ev) for k, ev in self._waiters.items())
        out.extend((("interpreter turn", i), ev) for i, ev in enumerate(self._interp_waiting))
        return out

    def state(self, rel: Relative) -> tuple:
        """Everything that decides the engine's future besides its pending events (which the
        environment lists): where every stream stands, the instances waiting on inputs, ready
        or to be skipped, the host threads, the effects' state and every channel's flows."""
        host_threads = ((tuple(self._free_threads), tuple(rel.part(p) for p in self._part_queue))
                        if hasattr(self, "_free_threads") else ())
        return (
            tuple(self._stream_state(st, proc, rel) for st, proc in zip(self.streams, self.processes)),
            tuple(sorted((rel.key(k), v) for k, v in self._pending.items())),
            tuple(sorted(rel.key(k) for k in self._ready)),
            tuple(sorted((rel.key(k), rel.t(v)) for k, v in self._cross_done.items())),
            tuple(sorted(rel.key(k) for k in self._skip)),
            self._chains.state(rel.key),
            host_threads,
            (self._interp_busy, len(self._interp_waiting)),
            self._busy_wake.state(self.env.now) if self._busy_wake is not None else None,
            tuple(ch.state(rel) for ch in self.channels.values()),
        )

    def _stream_state(self, st: _Stream, proc: simpy.Process, rel: Relative) -> tuple:
        """Where a stream waits, on what, at which frame and task, and the values it still uses
        from there (see `_Stream`)."""
        if not proc.is_alive:
            return ("finished",)
        target = proc.target if st.target is None else st.target
        out: tuple = (st.at, rel.event(target), rel.f(st.frame), rel.op(st.op))
        if st.at in (TURN, DISPATCH):
            out += (st.wait,)
        elif st.at in (RUN, TRANSFER):
            out += (rel.t(st.start),)
        if not st.host:
            out += (self._submit_clock(st.submitted, rel, st.frame),)
        return out

    def _submit_clock(self, value: int, rel: Relative, frame: int) -> int | None:
        """A queue's submit-thread clock. It only ever matters through max(clock, input end +
        dispatch), with every such input end at least the earliest one still pending (or now),
        and through the wait while it is ahead of now. Without a submit cost all clocks below
        that floor are the same state. With one, a clock so far behind the floor that every
        task left in the run (from the stream's `frame` on) could not bring it up to it never
        delays a task again, and the next input from elsewhere resets it: all such clocks are
        the same state too (a queue whose submit thread runs ahead of it, as on one GPU)."""
        if not self._host_timeline:
            return None
        floor = min([self.env.now] + [d + self._dispatch_ns for d in self._cross_done.values()])
        if self._submit_ns == 0:
            value = max(value, floor)
        elif value + self._submit_ns * self._tasks_in(frame, self.horizon) <= floor:
            return None
        return rel.t(value)

    # ----- run ---------------------------------------------------------------------------
    def all_ops(self) -> list[list[Op]]:
        """Every task's Op, per frame phase, in submission order."""
        return self._ops

    def shorten(self, frames: int) -> None:
        """Stop the run after `frames` frames (fewer than now). Only safe while no process has
        reached frame `frames - 1` (the fast-forward checks this)."""
        self._unfinished -= self._tasks_in(frames, self.horizon)
        self.horizon = frames

    def _tasks_in(self, first: int, end: int) -> int:
        """Task instances of frames [first, end): whole periods counted at once, so that a
        10^6-frame run does not count frame by frame at start-up."""
        per_phase = [len(t) for t in self.program.templates]
        cycles, rest = divmod(end - first, len(per_phase))
        return cycles * sum(per_phase) + sum(per_phase[f % len(per_phase)] for f in range(first, first + rest))

    def run(self) -> RawResult:
        try:
            self.env.run()
        except OverflowError:  # a time stored in int64 arrays passed 2^63 ns
            raise InputError(f"simulated time passed {INT64_MAX} ns (about 292 years), the int64 "
                             f"limit, within {self.program.frames} frames: fewer frames or shorter "
                             "tasks") from None
        if self._unfinished:
            raise ScheduleError(self._blocked_message())
        ch = self.channels
        links = {n: c for n, c in ch.items() if not n.startswith("host.") and not n.endswith(".exec")}
        effects: dict[str, bool | list[str]] = {
            "link_model": bool(links),
            "link_contention": any(c.max_concurrent > 1 for c in links.values()),
            "host_copies": "host.memory" in ch,
            "host_memory_contention": "host.memory" in ch and ch["host.memory"].max_concurrent > 1,
        }
        if "host.cpu" in ch:  # only reported for CPU-emulated GPUs (lavapipe profiles)
            effects["cpu_contention"] = ch["host.cpu"].max_concurrent > 1
        gpus = [c for n, c in ch.items() if n.endswith(".exec")]
        if gpus:  # only reported where queues of one physical GPU share it (shared_gpu)
            effects["gpu_contention"] = any(c.max_concurrent > 1 for c in gpus)
        raw = RawResult(self.rows, np.frombuffer(self.frame_start, dtype=np.int64),
                        np.frombuffer(self.present_end, dtype=np.int64), self.channels,
                        {n: len(f) for n, f in self._chains.skipped_frames.items()}, effects,
                        dict(self._chains.skipped_frames), present_task=self.program.present_task,
                        inputs=self.inputs)
        # The logs are the result's alone from here: the engine sits in reference cycles (its
        # processes and their environment) that only the cyclic collector frees, later, and a
        # 10^7-frame run's two frame arrays are 153 MB.
        self.rows, self.frame_start, self.present_end = [], array("q"), array("q")
        return raw

    def _blocked_message(self) -> str:
        blocked = sorted(self._waiters)[:8]
        names = ", ".join(f"frame {f} {n}" for f, n in blocked)
        return (f"schedule {self.program.schedule!r} cannot finish: {self._unfinished} task(s) never "
                f"ran; blocked waiting on dependencies: {names or 'none (a queue is stuck)'}")


class _Presented(Callback):
    """Vsync: the frame is shown at its refresh, and its present completes."""

    __slots__ = ("engine", "frame", "op")

    def __init__(self, engine: Engine, frame: int, op: Op):
        self.engine, self.frame, self.op = engine, frame, op

    def __call__(self, _event: simpy.Event) -> None:
        self.engine._presented(self.frame, self.op)

    def state(self, rel: Relative) -> tuple:
        return ("presented", rel.f(self.frame), rel.op(self.op))


class _PartCopy(Callback, tuple):
    """(engine, memcpy thread, part, start): a host copy's part has spent its fixed cost and
    starts copying. A tuple: made at C speed, for every part."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        self[0]._part_copy(self[1], self[2], self[3])

    def state(self, rel: Relative) -> tuple:
        return ("part copy", self[1], rel.part(self[2]), rel.t(self[3]))


class _PartStart(Callback, tuple):
    """(engine, thread, part): the thread its copy started for a part is up; the part starts."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        self[0]._start_part(self[1], self[2])

    def state(self, rel: Relative) -> tuple:
        return ("part start", self[1], rel.part(self[2]))


class _PartDone(_PartCopy):
    """(engine, memcpy thread, part, start): a host copy's part has crossed."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        self[0]._part_done(self[1], self[2], self[3])

    def state(self, rel: Relative) -> tuple:
        return ("part done", self[1], rel.part(self[2]), rel.t(self[3]))
