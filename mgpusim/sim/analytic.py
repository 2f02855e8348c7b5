"""The `analytic` fidelity level: frame times from the task graph, without event simulation.

Every task instance starts at the latest of: the ends of its dependencies (same and earlier
frames: buffers and frames in flight are such dependencies), the end of the task before it on
its queue, and (with host submission) its queue's submit clock; it ends after its pass or copy
time. Links run at their fixed rate. That is a max-plus recurrence over frames, evaluated task by
task in a topological order of each frame, with no event queue and no processes. Host copies are
split into parts over the memcpy threads exactly as the event model does (each part on the first
free thread, in dispatch order).

Exact where nothing is shared: it equals the event model whenever the scene needs none of link
sharing, host memory sharing and the shared executor (tests check it on every shipped
experiment that qualifies). Otherwise shared links and host memory are taken as if each
transfer had them alone (an optimistic bound: sharing only slows the model down), so are the
queues of one GPU that share it (shared_gpu: no piece of work runs faster shared than alone),
and CPU-emulated GPUs are taken as independent devices; skippable tasks follow the event model's rule,
decided from times. The summary lists the approximations made.

The recurrence's state at a frame boundary (recent task ends, queue clocks, thread free times),
relative to the frame's present, repeats once it is periodic; from then on frames are
extrapolated (the same composition as the event model's fast-forward), so a 10^6-frame run costs
what its first periodic frames cost. Where no state repeats but each period moves every state
value by its own constant (a pipeline still filling), one period run on lines fills the frames
to the end of the run in (:mod:`mgpusim.sim.affine`, :meth:`_Recurrence.stretch_to_end`).
:mod:`mgpusim.sim.analytic_lanes` evaluates many configurations of one program at once with
numpy (one array lane per configuration).
"""
from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Callable

import numpy as np

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError, ScheduleError
from mgpusim.model.geometry import even_split
from mgpusim.model.limits import MAX_RECORDED_FRAMES
from mgpusim.model.profile import HostProfile
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, Task
from mgpusim.results.periodic import RowColumns
from mgpusim.results.trace import TRACE_COLUMNS
from mgpusim.schedules.base import FrameProgram, leads_chain, wakes_host
from mgpusim.schedules.skipping import SkipChains
from mgpusim.schedules.task_inputs import TaskInputs
from mgpusim.sim import affine
from mgpusim.sim.channel import FixedRateChannel
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.engine import RawResult
from mgpusim.sim.executors import make_executors
from mgpusim.sim.fastforward import Repeat, Unrepeated
from mgpusim.sim.ops import Op, OpBuilder
from mgpusim.sim.snapshot import Environment

NEG = -(1 << 62)  # "no constraint" (before time 0)
NO_START = np.iinfo(np.int64).max  # a frame with no task run yet (its start array's fill)
#: The fewest whole periods left for a stretch to be tried (:meth:`_Recurrence.stretch_to_end`):
#: a try runs a period on lines and checks it, several frames' work, which fewer frames left
#: would not repay.
STRETCH_PERIODS = 8


@dataclass(frozen=True)
class _Node:
    """One task of a frame phase, with what the recurrence needs, precomputed."""

    name: str
    task: Task
    stream: str  # queue name, or "host" for host copies (dispatched in order)
    #: (task name, frame offset <= 0, crosses devices or the host)
    deps: tuple[tuple[str, int, bool], ...]
    fixed: int  # pass time, or copy setup (+ latency), or a host-copy part's fixed time
    nbytes: int
    rate: Fraction | None  # a copy's fixed link rate; a host copy's part rate
    gap: int
    parts: tuple[int, ...]  # host copy: the part sizes
    device: str
    engine: str
    waits_for: int  # the task's id in the program's TaskInputs
    #: a CPU task: its thread wakes after an input from elsewhere, with no submit cost
    cpu: bool = False
    #: precomputed for the recurrence: a queue task's whole time (fixed + bytes at its rate);
    #: a host copy's parts as (size, time) at the memcpy threads' rate
    time: int = 0
    part_times: tuple[tuple[int, int], ...] = ()
    step: str = ""  # the task's step (its trace rows'), read in the hot loop

    def __post_init__(self) -> None:
        object.__setattr__(self, "step", self.task.step)


def _with_times(node: _Node, times: _Node) -> _Node:
    """`node` with the times of `times` (its fixed time, bytes, rate, gap and whole time): a
    copy's node on other links. Made as a copy of its fields, not through `__init__`: a
    retimed model makes one per copy node, and the constructor took most of its time."""
    new = object.__new__(_Node)
    fields = new.__dict__
    fields.update(node.__dict__)
    fields.update(fixed=times.fixed, nbytes=times.nbytes, rate=times.rate, gap=times.gap, time=times.time)
    return new


def _round_div(nbytes: int, rate: Fraction) -> int:
    """bytes / rate, rounded half up, as the link channel computes it."""
    num, den = rate.numerator, rate.denominator
    return (2 * nbytes * den + num) // (2 * num)


def host_approximations(host: HostProfile) -> list[str]:
    """The host rules of `host` that the recurrence leaves out, one note each. Both are
    optimistic bounds: the recurrence wakes every thread at once and gives each its own
    interpreter, so a frame can only come out as fast as the event model's or faster. Empty:
    the host side adds nothing the recurrence cannot follow (on lavapipe the shared cores are
    the `shared_executor` effect instead)."""
    if host.gpus_share_cpu:
        return []
    out = []
    if host.serial_dispatch and host.dispatch_ns:
        out.append("serial_dispatch: host threads woken at once taken as waking together (an optimistic bound)")
    if host.shared_interpreter and (host.dispatch_ns or host.submit_ns):
        out.append("shared_interpreter: the runner's threads taken as each having an interpreter "
                   "of its own (an optimistic bound)")
    return out


#: The effects the recurrence leaves out: it takes every link, host memory, core and GPU as if
#: each piece of work had it alone (see the module doc and `Analytic._approximations`).
UNSHARED = frozenset({"shared_executor", "shared_gpu", "link_sharing", "host_pcie",
                      "host_memory_sharing", "busy_wake"})


def _builder(program: FrameProgram, costs: CostModel, effects: frozenset[str],
             inputs: TaskInputs | None = None) -> OpBuilder:
    """The engine's own rules for durations, rates and labels (:class:`.ops.OpBuilder`), on an
    environment that never runs: every device on its own executor and every link at its fixed
    rate (the recurrence takes everything as unshared), so each op's channel only says its
    bandwidth. Why not the engine itself: the recurrence needs none of its run state."""
    env = Environment()
    return OpBuilder(program, costs, effects - UNSHARED, env, make_executors(env, costs, shared=False),
                     inputs=inputs)


class Analytic:
    """The recurrence for one program and cost model (see the module doc)."""

    def __init__(self, program: FrameProgram, costs: CostModel, effects: frozenset[str],
                 needed: frozenset[str] | None = None):
        """`needed`: `choose_effects(program, costs.profile)` where the caller has it already
        (for the approximations the model lists)."""
        if program.refresh_hz:
            raise InputError("the analytic fidelity level does not model vsync: use --fidelity "
                             "queues or full", field="schedule.refresh_hz")
        self.program, self.costs, self.effects = program, costs, effects
        host = costs.profile.host
        submission = "host_submission" in effects
        self.dispatch = host.dispatch_ns if submission else 0
        self.submit = host.submit_ns if submission else 0
        self.copy_wake = host.host_copy_wake_ns if submission else 0
        self.timeline = bool(self.dispatch or self.submit or self.copy_wake)
        #: per frame phase, task name -> its task (a name may sit on other devices in other phases)
        self.task_of = [{t.name: t for t in tasks} for tasks in program.templates]
        # the skip rule's grouping refuses a skippable task behind two chains, as the engine
        # does (the recurrence groups them itself, :func:`_skip_chains`)
        SkipChains(program, self.task_of)
        builder = _builder(program, costs, effects)
        self.inputs = builder.inputs  # the ids the rows log, and what each lists
        self.threads = host.memcpy_threads
        #: a thread start before each part of a copy on threads of its own (host_frame_work)
        self.part_thread_ns = host.thread_start_ns if "host_frame_work" in effects else 0
        self.thread_names = [f"thread{i}" for i in range(self.threads)]
        self.host_memory = costs.host_memory_bandwidth()
        self.phases = [self._order([self._node(op, phase) for op in ops])
                       for phase, ops in enumerate(builder.all_ops())]
        self.lag = max([1] + [-d[1] for ph in self.phases for n in ph for d in n.deps])
        #: per phase, skippable task -> (its chain's leader, its same-frame skippable inputs)
        self.chains = [_skip_chains(ph) for ph in self.phases]
        self.approximations = self._approximations(needed)
        #: the present is a task on a GPU queue, as the rows' per-frame presents count it (a
        #: present on the host would leave the rows' present unset): the recurrence's own
        #: per-frame presents then stand for the rows'
        self.presents_on_gpu = all(n.device != "host" for ph in self.phases for n in ph
                                   if n.name == program.present_task)

    def _node(self, op: Op, phase: int) -> _Node:
        task = op.task
        deps = tuple((d.task, d.offset, self._crosses(task, d.task, (phase + d.offset) % len(self.task_of), phase))
                     for d in task.deps)
        return self._timed(op, deps)

    def _timed(self, op: Op, deps: tuple[tuple[str, int, bool], ...]) -> _Node:
        """The node of `op` with its dependencies `deps` (see `_node`) and its times."""
        task = op.task
        if isinstance(task, HostCopyTask):
            parts = tuple(even_split(task.bytes, task.parts(self.threads)))
            cap = op.cap
            assert cap is not None, "a host copy's op has its parts' cap (a memcpy thread's speed)"
            part_rate = cap if cap < self.host_memory else self.host_memory  # a part alone
            return _Node(task.name, task, "host", deps, op.duration, task.bytes, part_rate, 0, parts,
                         "host", "memcpy", op.waits_for,
                         part_times=tuple((size, op.duration + _round_div(size, part_rate)) for size in parts))
        if isinstance(task, CpuTask):
            return _Node(task.name, task, f"host.{task.thread}", deps, op.duration, 0, None, 0, (),
                         "host", task.thread, op.waits_for, cpu=True, time=op.duration)
        rate = None
        if op.channel is not None:  # (at its fixed rate: see _builder)
            assert isinstance(op.channel, FixedRateChannel)
            bw = op.channel.bandwidth
            rate = bw if op.cap is None or op.cap >= bw else op.cap
        moved = _round_div(op.nbytes, rate) if rate is not None and op.nbytes else 0
        return _Node(task.name, task, str(task.queue), deps, op.duration, op.nbytes, rate, op.gap, (),
                     op.device, op.engine, op.waits_for, time=op.duration + moved)

    def retimed(self, costs: CostModel, needed: frozenset[str] | None = None,
                program: FrameProgram | None = None) -> "Analytic":
        """This model on `costs`, a cost model whose profile differs from this one's only in its
        links' rates and latencies (the caller checks that: same GPUs, costs, host and peer
        topology), and on `program` where given: this model's program with some tasks' costs
        changed but none of their names, queues or inputs (an AFR program at another cadence,
        :func:`~mgpusim.schedules.afr.with_pace`). Why: `advise` runs one program over many
        links and cadences, and only the copies' times (and the pacer's) change; the task
        graph, its order, the frame lag and the skip chains are kept, and each copy's node and
        each changed task's is built again by the engine's own rules on `costs` (so its time,
        and the time bound it is checked against, are those a fresh model would have; copies
        alike in queue, path, peer and size are built once). Host copies stay: host memory and
        memcpy threads set their times, not a link. `needed`: `choose_effects(program,
        costs.profile)` where the caller has it already."""
        program = self.program if program is None else program
        builder = _builder(program, costs, self.effects, self.inputs)
        task_of = (self.task_of if program is self.program else
                   [{t.name: t for t in tasks} for tasks in program.templates])
        alike: dict[tuple, _Node] = {}

        def timed(phase: int, node: _Node) -> _Node:
            task = task_of[phase][node.name]
            if task is not node.task and task != node.task:  # its cost changed (the program's)
                return self._timed(builder.op(phase, task), node.deps)
            if not isinstance(task, CopyTask):
                return node
            key = (task.queue, task.path, task.peer, task.bytes)
            done = alike.get(key)
            if done is None:
                done = alike[key] = self._timed(builder.op(phase, task), node.deps)
            return _with_times(node, done)
        new = copy.copy(self)
        new.costs, new.program, new.task_of = costs, program, task_of
        new.phases = [[timed(ph, n) for n in phase] for ph, phase in enumerate(self.phases)]
        new.approximations = new._approximations(needed)
        return new

    def _crosses(self, task: Task, dep: str, dep_phase: int, phase: int) -> bool:
        """Whether a host thread must wake to act on this input (as the engine decides): the
        input's producer, in its own frame phase, is on another device or the host, or the
        task leads a skippable chain."""
        return wakes_host(self.task_of[dep_phase][dep], task, leads_chain(task, self.task_of[phase]))

    @staticmethod
    def _order(nodes: list[_Node]) -> list[_Node]:
        """Submission order within each stream, same-frame dependencies first."""
        by_name = {n.name: n for n in nodes}
        stream_prev: dict[str, str] = {}
        before: dict[str, set[str]] = {}
        for n in nodes:
            before[n.name] = {d for d, off, _ in n.deps if off == 0}
            if n.stream in stream_prev:
                before[n.name].add(stream_prev[n.stream])
            stream_prev[n.stream] = n.name
        out: list[_Node] = []
        done: set[str] = set()
        left = list(nodes)
        while left:  # the first node left (in submission order) whose inputs are done
            k = next((k for k, n in enumerate(left) if before[n.name] <= done), None)
            if k is None:
                raise ScheduleError("a frame's tasks depend on each other in a cycle")
            out.append(left.pop(k))
            done.add(out[-1].name)
        return [by_name[n.name] for n in out]

    def _approximations(self, needed: frozenset[str] | None = None) -> list[str]:
        if needed is None:
            needed = choose_effects(self.program, self.costs.profile)
        out = [f"{name}: taken as unshared (an optimistic bound)"
               for name in ("link_sharing", "host_pcie", "host_memory_sharing") if name in needed]
        if "shared_gpu" in needed:
            out.append("shared_gpu: the queues of each GPU taken as independent (an optimistic bound)")
        if "shared_executor" in needed:
            out.append("shared_executor: the emulated GPUs taken as independent devices (not a bound)")
        if "busy_wake" in needed:
            out.append("busy_wake: no copy waits behind another GPU's young pass (an optimistic bound)")
        return out + host_approximations(self.costs.profile.host)

    # ----- one configuration ---------------------------------------------------------------
    def evaluate(self, record: bool = True, progress: Callable[[int, int], None] | None = None
                 ) -> "_Run":
        """One run of the recurrence: rows, frame starts, presents, the repeat (None: every
        frame computed, or the arrays already extended when no rows were asked for), the
        repeat found, skipped frames and tied skip decisions, with the frames past those
        computed filled in (:meth:`_extended`). A run of more than MAX_RECORDED_FRAMES frames
        whose state has not repeated by then raises :class:`~.fastforward.Unrepeated` there
        (the loop's own bound: no test per frame). The model itself is left as it was built, so
        that one model serves many runs (simulate() keeps it per experiment,
        :mod:`mgpusim.sim.prepared`)."""
        rec = _Recurrence(self, record)
        frames = self.program.frames
        horizon, repeat, f = frames, None, 0
        stop = min(horizon, MAX_RECORDED_FRAMES)  # (past it only once a repeat shortened the run)
        step = max(1, frames // 200)
        while f < stop:
            if progress is not None and f % step == 0:
                progress(f, horizon)
            rec.frame(f)
            if repeat is None and f >= self.lag:
                repeat = rec.look_for_repeat(f)
                if repeat is not None:
                    horizon = stop = frames - repeat.copies * repeat.frames
                elif rec.found is None and rec.stretch_to_end(f):
                    break  # every frame after f filled in from one period (mgpusim.sim.affine)
            rec.forget_before(f - self.lag)
            f += 1
        else:
            if f < horizon:
                raise Unrepeated(f"no repeat within the first {f:,} frames")
        if progress is not None:
            progress(horizon, horizon)
        rows = rec.rows if rec.columns is None else rec.columns
        run = _Run(rows, rec.start, rec.present, repeat, rec.found, rec.skips.ties, rec.skips.frames)
        return self._extended(run, horizon, record)

    def _extended(self, run: "_Run", computed: int, record: bool) -> "_Run":
        """`run` with its frames from `computed` on filled in from its repeat, the one place
        the arrays are extended. Why here: the state repeats, so each such frame is the one a
        period earlier, shifted, which is what the rows' repeat would give; extending the
        arrays spares building them from the rows. Without rows (`record` off) the skipped
        frames are continued too and the repeat is dropped (nothing left to compose). With
        rows, the arrays stand for the rows' only when the present is a GPU task (see
        `presents_on_gpu`); otherwise they are left to be built from the rows."""
        repeat = run.repeat
        if repeat is None or (record and not self.presents_on_gpu):
            return run
        _extend(run.start, computed, repeat)
        _extend(run.present, computed, repeat)
        run.frames_whole = True
        if not record:
            run.skipped_frames = {n: _extend_frames(v, computed, self.program.frames, repeat.frames)
                                  for n, v in run.skipped_frames.items()}
            run.repeat = None
        return run


@dataclass
class _Run:
    """One evaluation of the recurrence (see :meth:`Analytic.evaluate`)."""

    rows: list[tuple] | RowColumns
    start: np.ndarray
    present: np.ndarray
    repeat: Repeat | None
    found: dict[str, int] | None
    ties: int
    skipped_frames: dict[str, list[int]]
    #: `start` and `present` cover every frame, those past the computed ones included
    frames_whole: bool = False


class _Recurrence:
    """The recurrence's state while it runs: recent task ends, each stream's clock (when its
    queue is free, its submit clock), the memcpy threads, and the skip chains."""

    def __init__(self, model: Analytic, record: bool):
        self.m, self.record = model, record
        frames = model.program.frames
        self.ends: list[dict[str, int]] = []
        self.queue_end: dict[str, int] = {}
        self.sub: dict[str, int] = {}
        self.threads = [0] * model.threads
        self.host_prev = NEG
        self.rows: list[tuple] = []
        #: every row as columns, where a stretch filled the frames after the rows in (else None)
        self.columns: RowColumns | None = None
        self.start = np.full(frames, NO_START, dtype=np.int64)
        self.present = np.full(frames, -1, dtype=np.int64)
        self.skips = _Skips()
        #: (phase, queues' clocks relative to the present) -> [snapshot, its state or None]
        self.seen: dict[tuple, list[list]] = {}
        self.found: dict[str, int] | None = None
        #: the snapshots of the last two periods and one frame (:meth:`stretch_to_end` reads them)
        self.recent: deque[tuple] = deque(maxlen=2 * len(model.phases) + 1)
        #: the first frame at which to look for an affine stretch again
        self.next_try = 0
        self.gap = 1

    # ----- one frame ---------------------------------------------------------------------
    def frame(self, f: int) -> None:
        """Every task of frame f, in the phase's order. (The hot loop: inputs read inline.) A
        queue task starts after its inputs, the task before it on its queue and (with host
        submission) its submit clock, then spends its gap, its pass or copy time and its
        bytes at the link's fixed rate; a CPU task's thread wakes on its input from
        elsewhere and submits nothing."""
        m = self.m
        phase = f % len(m.phases)
        here: dict[str, int] = {}
        ends = self.ends
        ends.append(here)
        first = NO_START
        skipped_here: set[str] = set()
        chains = m.chains[phase]
        queue_end, sub, rows = self.queue_end, self.sub, self.rows if self.record else None
        timeline, dispatch, submit = m.timeline, m.dispatch, m.submit
        for node in m.phases[phase]:
            ready, cross, has_deps = NEG, NEG, False
            for dep, off, crosses in node.deps:
                if off:
                    if f + off < 0:
                        continue
                    e = ends[f + off][dep]
                else:
                    e = here[dep]
                has_deps = True
                if e > ready:
                    ready = e
                if crosses and e > cross:
                    cross = e
            chain = chains.get(node.name) if chains else None
            if chain is not None and self._skip(node, f, chain, skipped_here, here, ready, has_deps):
                continue
            stream = node.stream
            if stream == "host":
                e, first = self._host_copy(node, f, ready, cross, first)
            else:  # _queue_task, inline
                s = queue_end.get(stream, 0)
                if ready > s:
                    s = ready
                if timeline:
                    if node.cpu:
                        if cross > NEG and cross + dispatch > s:
                            s = cross + dispatch
                    else:
                        clock = sub.get(stream, 0)
                        if cross > NEG and cross + dispatch > clock:
                            clock = cross + dispatch
                        clock += submit
                        sub[stream] = clock
                        if clock > s:
                            s = clock
                s += node.gap
                e = queue_end[stream] = s + node.time
                if s < first:
                    first = s
                if rows is not None:
                    rows.append((f, node.device, node.engine, node.step, node.name, s, e, node.nbytes,
                                 node.waits_for))
            here[node.name] = e
            if chain is not None:
                self.skips.ran(chain[0], e)
        if first != NO_START:
            self.start[f] = first
        self.present[f] = here[m.program.present_task]

    def _skip(self, node: _Node, f: int, chain: tuple[str, tuple[str, ...] | None], skipped_here: set[str],
              here: dict[str, int], ready: int, has_deps: bool) -> bool:
        """Apply the skip rule; a skipped task ends when its stream reaches it, and the stream
        moves on from there."""
        arrive = max(self.host_prev, 0) if node.stream == "host" else self.queue_end.get(node.stream, 0)
        if not self.skips.skipped(chain, skipped_here, ready if has_deps else arrive):
            return False
        skipped_here.add(node.name)
        self.skips.frames.setdefault(node.name, []).append(f)
        here[node.name] = t = max(ready, arrive)
        if node.stream == "host":
            self.host_prev = t
        else:
            self.queue_end[node.stream] = t
        return True

    def _host_copy(self, node: _Node, f: int, ready: int, cross: int, first: int) -> tuple[int, int]:
        """Dispatched in order (after the host wakes), split over the memcpy threads, each part
        on the lowest-numbered idle thread, else the first to become idle (the engine's pool).
        Returns its end and the frame's first start so far."""
        t = max(ready, self.host_prev, 0)
        if self.m.timeline and cross > NEG:
            t = max(t, cross + self.m.copy_wake + self.m.dispatch)
        self.host_prev = t
        if isinstance(node.task, HostCopyTask) and node.task.own_threads:
            return self._own_threads(node, node.task, f, t, first)
        end, threads, names = NEG, self.threads, self.m.thread_names
        rows = self.rows if self.record else None
        for size, took in node.part_times:
            for tid, s in enumerate(threads):  # noqa: B007 - `tid`, the thread found, is read after the loop
                if s <= t:
                    s = t
                    break
            else:  # every thread busy: the first free (lowest-numbered among equals)
                s = min(threads)
                tid = threads.index(s)
            e = threads[tid] = s + took
            if e > end:
                end = e
            if s < first:
                first = s
            if rows is not None:
                rows.append((f, "host", names[tid], node.step, node.name, s, e, size, node.waits_for))
        return end, first

    def _own_threads(self, node: _Node, task: HostCopyTask, f: int, t: int, first: int) -> tuple[int, int]:
        """A copy on threads of its own: each part from its start (`HostCopyTask.part_start_ns`,
        the thread starts only with host_frame_work), each alone (host memory as if unshared,
        as for the pool's parts). Returns its end and the frame's first start."""
        end, parts = NEG, len(node.part_times)
        for k, (size, took) in enumerate(node.part_times):
            s = t + task.part_start_ns(k, parts, self.m.part_thread_ns)
            end = max(end, s + took)
            first = min(first, s)
            if self.record:
                self.rows.append((f, "host", f"{node.name}.thread{k}", node.step, node.name, s, s + took, size,
                                  node.waits_for))
        return end, first

    def forget_before(self, f: int) -> None:
        if f > 0:
            self.ends[f - 1] = {}  # never read again

    # ----- the repeat --------------------------------------------------------------------
    def look_for_repeat(self, f: int) -> Repeat | None:
        """Note frame f's state; at its second sight, the repeat (None if nothing to skip).

        The state (:meth:`_state`) is written relative to the frame's present only when a
        part of it, the phase and the queues' clocks, was met before: until then frame f's
        values are kept as they are (a few tuples, C speed), to be written relative later if
        needed. Same repeat, found at the same frame, as writing every frame's state."""
        ref = int(self.present[f])
        snap = self._snapshot(f, ref)
        self.recent.append(snap)
        cheap = (f % len(self.m.phases), tuple(map(ref.__rsub__, self.queue_end.values())))
        candidates = self.seen.get(cheap)
        if candidates is None:
            self.seen[cheap] = [[snap, None]]
            return None
        key = self._state(snap)
        earlier = None
        for entry in candidates:  # their states differ from each other: one at most matches
            if entry[1] is None:
                entry[1] = self._state(entry[0])
            if entry[1] == key:
                earlier = entry[0]
                break
        if earlier is None:
            candidates.append([snap, key])
            return None
        self.seen.clear()
        f1, t1, r1, m1 = earlier[:4]
        marks = snap[3]
        p, shift = f - f1, ref - t1
        self.found = {"period_frames": p, "period_ns": shift, "from_frame": f1 + 1}
        copies = max(0, (self.m.program.frames - (f + 2)) // p)
        if not copies:
            return None
        return Repeat(p, shift, copies, f1 + 1, (r1, len(self.rows)),
                      skipped={n: (m1.get(n, 0), k) for n, k in marks.items()})

    # ----- an affine stretch to the end of the run ----------------------------------------
    def stretch_to_end(self, f: int) -> bool:
        """Fill in every frame after f from one period of the recurrence on lines
        (:mod:`mgpusim.sim.affine`), where the last two periods moved every state value by the
        same amount each and the period, run on lines over the frames left, keeps its
        decisions and leads from each step to the next. True where it did (the run is then
        whole); False leaves the run as it was. Why only to the end of the run: the frames it
        fills are never looked at for a repeat, so it also checks that none of them would have
        been found as one (no state of the stretch equals an earlier one, and none equals
        another), and then the run reports what frame by frame would have: the same rows,
        presents, skips, ties and repeat (none). So a run of more than MAX_RECORDED_FRAMES
        frames, which may go on only once it has repeated, is refused here (Unrepeated): it
        never will, and the stretch would hold every frame's rows."""
        if f < self.next_try:
            return False
        p, frames = len(self.m.phases), self.m.program.frames
        steps, left = divmod(frames - 1 - f, p)
        recent = self.recent
        if steps < STRETCH_PERIODS or len(recent) < 2 * p + 1 or not _steady(recent[-1], recent[-1 - p],
                                                                             recent[-1 - 2 * p]):
            self._later(self.gap)
            return False
        try:
            out = self._stretch(f, self.recent[-1], self.recent[-1 - p], steps if left else steps - 1)
        except affine.Indefinite as exc:  # a decision flips after exc.last periods: no use before
            self._later(max(self.gap, (exc.last + 1) * p))
            return False
        if out is None:
            self._later(self.gap)
            return False
        if frames > MAX_RECORDED_FRAMES:  # no state repeats to the end: it would keep every frame's rows
            raise Unrepeated(f"the state never repeats (from frame {f + 1} every period moves each "
                             "time by its own constant)")
        self._fill(f, *out)
        return True

    def _later(self, frames: int) -> None:
        self.next_try = len(self.ends) + frames
        self.gap = min(2 * self.gap, 64)

    def _stretch(self, f: int, now: tuple, before: tuple, span: int) -> tuple | None:
        """One period after frame f on lines over j = 0..span, from the snapshots of frames f
        and f - P: (the run on lines, its ties per frame) where it continues itself and no
        state in it could be a repeat; None where not. Raises affine.Indefinite."""
        m, p = self.m, len(self.m.phases)
        sym: Any = _Recurrence.__new__(_Recurrence)  # its times are lines (affine.Lin), not ints
        sym.m, sym.record, sym.rows = m, self.record, []
        sym.start, sym.present = {}, {}  # lines per frame
        ends = [{k: affine.lifted(v, old[k], span) for k, v in new.items()} for new, old in zip(now[4], before[4])]
        sym.ends = [{}] * (f + 1 - len(ends)) + ends
        sym.queue_end = _lines(now[5], before[5], span)
        sym.sub = _lines(now[6], before[6], span)
        sym.threads = [affine.lifted(a, b, span) for a, b in zip(now[7], before[7])]
        sym.host_prev = affine.lifted(now[8], before[8], span)
        sym.skips = _Skips()
        sym.skips.busy_until = _lines(now[9][0], before[9][0], span)
        sym.skips.last_ready = _lines(now[9][1], before[9][1], span)
        start = dict(queue=dict(sym.queue_end), sub=dict(sym.sub), threads=list(sym.threads),
                     host=sym.host_prev, busy=dict(sym.skips.busy_until), last=dict(sym.skips.last_ready))
        ties, states = [], []
        for g in range(f + 1, f + p + 1):
            before_ties = sym.skips.ties
            sym.frame(g)
            ties.append(sym.skips.ties - before_ties)
            states.append(sym._state(sym._snapshot(g, sym.present[g])))
        if not _continues(sym, start, ends, f, p) or not all(map(affine.drifts, states)):
            return None
        for (phase, clocks), candidates in self.seen.items():  # a state met before: a repeat
            # (first the quick key, which an equal state has: its phase and queues' clocks)
            like = [s for s in states if s[0] == phase and affine.solve(s[3], clocks, span) != set()]
            for entry in candidates if like else ():
                if entry[1] is None:
                    entry[1] = self._state(entry[0])
                if any(affine.solve(s, entry[1], span) != set() for s in like):
                    return None
        return sym, ties

    def _fill(self, f: int, sym: Any, ties: list[int]) -> None:
        """Frames f + 1 .. the last from the period on lines `sym` (see :meth:`stretch_to_end`)."""
        p, frames = len(self.m.phases), self.m.program.frames
        for g in range(f + 1, f + p + 1):
            idx = np.arange(g, frames, p, dtype=np.int64)
            j = np.arange(len(idx), dtype=np.int64)
            for mine, lines in ((self.start, sym.start), (self.present, sym.present)):
                if g in lines:
                    a, b = affine.parts(lines[g])
                    mine[idx] = a + b * j
            self.skips.ties += ties[g - f - 1] * len(idx)
        steps = (frames - 1 - f + p - 1) // p
        for name, skipped in sym.skips.frames.items():
            self.skips.frames.setdefault(name, []).extend(
                g + j * p for j in range(steps) for g in skipped if g + j * p < frames)
        if self.record:
            self.columns = _columns(self.rows, sym.rows, p, steps, frames - 1)

    def _snapshot(self, f: int, ref: int) -> tuple:
        """Frame f's state as it is (absolute times): (frame, its present, rows so far,
        skipped instances so far per task, the recent frames' ends (their dictionaries, never
        changed once their frame is done), the queues' clocks, the submit clocks, the
        threads, the host's last dispatch, the skip chains')."""
        skips = self.skips
        return (f, ref, len(self.rows), {n: len(v) for n, v in skips.frames.items()},
                self.ends[max(0, f - self.m.lag + 1):f + 1], tuple(self.queue_end.items()),
                tuple(self.sub.items()), tuple(self.threads), self.host_prev,
                (tuple(skips.busy_until.items()), tuple(skips.last_ready.items())))

    def _state(self, snap: tuple) -> tuple:
        """What the frames after a snapshot's frame read, relative to its present. A thread
        idle since before the last dispatch and a submit clock (without submit cost) behind
        its queue are the same state whatever their exact value, so they are written as those
        bounds."""
        f, ref, _rows, _marks, recent_ends, queue_items, sub_items, threads, host_prev, skips = snap
        m, minus = self.m, ref.__rsub__  # minus(x) = x - ref
        # Ends and clocks are never NEG. A frame's ends are in its phase's task order (the phase
        # is in the state), the clocks in the order the streams first ran: values alone, in
        # order, with the streams' names once.
        recent = tuple([tuple(map(minus, ends.values())) for ends in recent_ends])
        queue_end = dict(queue_items)
        if m.submit:
            clocks = tuple([c - ref for _q, c in sub_items])
        else:
            clocks = tuple([max(c, queue_end.get(q, 0)) - ref for q, c in sub_items])
        idle = max(host_prev, 0)
        return (f % len(m.phases), recent, tuple(queue_end), tuple(map(minus, queue_end.values())),
                tuple([q for q, _c in sub_items]), clocks, tuple([t - ref if t > idle else None for t in threads]),
                host_prev - ref if host_prev > NEG else NEG) + _Skips.relative(skips, ref)


class _Skips:
    """The skip rule of the event model (mgpusim.schedules.skipping), decided from times: a chain's
    leader is skipped when a task of an earlier instance of its chain that ran ends after the
    leader's inputs are ready; a follower when one of its skippable inputs of the frame was."""

    def __init__(self) -> None:
        self.busy_until: dict[str, int] = {}  # chain -> latest end of its tasks that ran
        self.last_ready: dict[str, int] = {}  # chain -> latest decision time of a leader that ran
        self.frames: dict[str, list[int]] = {}  # task -> frames it was skipped in
        #: decisions the times alone cannot settle (an end at the very decision time, or a
        #: decision earlier than one before it): the event order decides them in the model
        self.ties = 0

    def skipped(self, chain: tuple[str, tuple[str, ...] | None], skipped_here: set[str], at: int) -> bool:
        leader, inputs = chain
        if inputs is not None:
            return any(n in skipped_here for n in inputs)
        busy = self.busy_until.get(leader, NEG)
        if busy == at or self.last_ready.get(leader, NEG) > at:
            self.ties += 1
        if busy > at:
            return True
        self.last_ready[leader] = max(self.last_ready.get(leader, NEG), at)
        return False

    def ran(self, leader: str, end: int) -> None:
        self.busy_until[leader] = max(self.busy_until.get(leader, NEG), end)

    @staticmethod
    def relative(items: tuple[tuple, tuple], ref: int) -> tuple:
        """The chains' state from (busy_until items, last_ready items), relative to `ref`."""
        busy, last = items
        if not busy and not last:
            return ((), ())  # no skippable task has run yet (or the program has none)

        def rel(x: int) -> int:
            return x - ref if x > NEG else NEG
        return (tuple(sorted((k, rel(v)) for k, v in busy)), tuple(sorted((k, rel(v)) for k, v in last)))


def _columns(prefix: list[tuple], block: list[tuple], p: int, steps: int, last: int) -> RowColumns:
    """The rows logged so far, then `steps` periods of the rows of one period on lines
    (`block`: start and end as affine.Lin), each `p` frames and each row's slopes later, those
    of frames after `last` left out: as columns (no tuple per row)."""
    n = len(block)
    kept = (steps - 1) * n + sum(1 for row in block if row[0] + (steps - 1) * p <= last)
    j = np.repeat(np.arange(steps, dtype=np.int64), n)[:kept]
    head = list(zip(*prefix)) if prefix else [()] * len(TRACE_COLUMNS)
    body = list(zip(*block))
    cols: dict[str, Any] = {}
    for k, name in enumerate(TRACE_COLUMNS):
        if k in (5, 6):  # start, end: lines
            a, b = (np.array(v, dtype=np.int64) for v in zip(*map(affine.parts, body[k])))
            values = np.tile(a, steps)[:kept] + np.tile(b, steps)[:kept] * j
        elif name in ("frame", "bytes", "waits_for"):
            values = np.tile(np.array(body[k], dtype=np.int64), steps)[:kept]
            if k == 0:
                values += j * p
        else:
            cols[name] = list(head[k]) + (list(body[k]) * steps)[:kept]
            continue
        cols[name] = np.concatenate([np.array(head[k], dtype=np.int64), values])
    pairs = list(zip(head[1], head[2])), list(zip(body[1], body[2]))  # (device, engine)
    index = {pair: i for i, pair in enumerate(dict.fromkeys(pairs[0] + pairs[1]))}
    codes = np.concatenate([np.array([index[q] for q in pairs[0]], dtype=np.int64),
                            np.tile(np.array([index[q] for q in pairs[1]], dtype=np.int64), steps)[:kept]])
    return RowColumns(cols, (codes, [f"{device}.{engine}" for device, engine in index]))


def _steady(now: tuple, before: tuple, earlier: tuple) -> bool:
    """Whether the last two periods moved every state value of three snapshots (one period
    apart) by the same amount each, the names alike: worth trying a stretch from."""
    flat = [_values(s) for s in (now, before, earlier)]
    if flat[0][0] != flat[1][0] or flat[1][0] != flat[2][0]:
        return False
    (_, a), (_, b), (_, c) = flat
    return all(x - y == y - z for x, y, z in zip(a, b, c))


def _values(snap: tuple) -> tuple[tuple, list[int]]:
    """(the names and sizes, every value) of a snapshot's state."""
    ends, queues, subs, threads, host_prev, (busy, last) = snap[4:10]
    names = (tuple(map(len, ends)), tuple(k for k, _ in queues), tuple(k for k, _ in subs), len(threads),
             tuple(k for k, _ in busy), tuple(k for k, _ in last))
    values = [v for e in ends for v in e.values()]
    for items in (queues, subs, busy, last):
        values += [v for _k, v in items]
    return names, values + list(threads) + [host_prev]


def _lines(now: tuple, before: tuple, span: int) -> dict[str, affine.Lin]:
    """A snapshot's (name, value) items as lines, from the same items one period earlier."""
    old = dict(before)
    return {k: affine.lifted(v, old[k], span) for k, v in now}


def _continues(sym: Any, start: dict, ends: list[dict], f: int, p: int) -> bool:
    """Whether the period on lines `sym` ends in its start state one step on: every value
    after it is the line it started from, moved by its slope, under the same names."""
    def same(out: dict, was: dict) -> bool:
        return list(out) == list(was) and all(affine.continues(out[k], was[k]) for k in was)
    lag = len(ends)
    if not all(same(sym.ends[f + p - lag + 1 + i], ends[i]) for i in range(lag)):
        return False
    if not (same(sym.queue_end, start["queue"]) and same(sym.sub, start["sub"])
            and same(sym.skips.busy_until, start["busy"]) and same(sym.skips.last_ready, start["last"])):
        return False
    return (all(map(affine.continues, sym.threads, start["threads"]))
            and affine.continues(sym.host_prev, start["host"]))


def _skip_chains(nodes: list[_Node]) -> dict[str, tuple[str, tuple[str, ...] | None]]:
    """Skippable task -> (its chain's leader, its same-frame skippable inputs or None for a
    leader), as mgpusim.schedules.skipping groups them."""
    out: dict[str, tuple[str, tuple[str, ...] | None]] = {}
    for n in nodes:
        if not n.task.skip_if_busy:
            continue
        ins = tuple(d for d, off, _ in n.deps if off == 0 and d in out)
        out[n.name] = (out[ins[0]][0], ins) if ins else (n.name, None)
    return out


def _extend_frames(frames: list[int], computed: int, total: int, period: int) -> list[int]:
    """A task's skipped frames, continued periodically from frame `computed` to `total`."""
    flags = np.zeros(total, dtype=bool)
    flags[frames] = True
    for f in range(computed, total, period):
        n = min(period, total - f)
        flags[f:f + n] = flags[f - period:f - period + n]
    return np.flatnonzero(flags).tolist()


def _extend(values: np.ndarray, computed: int, repeat: Repeat) -> None:
    """Fill frames from `computed` on: each is the one `repeat.frames` earlier plus the shift."""
    p, t = repeat.frames, repeat.ns
    k = np.arange(len(values) - computed, dtype=np.int64)
    if len(k):  # frame computed + k: the one of the last computed period, k // p + 1 steps on
        values[computed:] = values[computed - p + k % p] + t * (k // p + 1)


def model_raw(model: Analytic, record_trace: bool = True,
              progress: Callable[[int, int], None] | None = None):
    """A RawResult from the recurrence of a model already built (which it leaves as it was),
    for :func:`mgpusim.results.summary.build_result`. `progress(done, total)`: frames computed
    and frames to compute, now and then."""
    out = model.evaluate(record=record_trace, progress=progress)
    program = model.program
    skipped = {n: len(v) for n, v in out.skipped_frames.items()}
    raw = RawResult(out.rows, out.start, out.present, {}, skipped, {}, dict(out.skipped_frames),
                    present_task=program.present_task, inputs=model.inputs)
    raw.recorded = record_trace
    raw.repeat = out.repeat
    raw.frames_whole = out.frames_whole
    found = out.found
    raw.fast_forward = {"used": found is not None}
    if found is None:
        raw.fast_forward["why"] = "no repeat found"
    else:
        raw.fast_forward.update(why=f"state repeats every {found['period_frames']} frame(s), "
                                    f"{found['period_ns']} ns, from frame {found['from_frame']}", **found)
    approximations = list(model.approximations)
    if out.ties:
        approximations.append(f"skippable tasks: {out.ties} skip decision(s) tied with a chain's end "
                              "(taken as finished)")
    raw.effects = {"analytic_exact": not approximations}
    if approximations:
        raw.effects["analytic_approximations"] = approximations
    return raw
