"""The SimPy executor: runs a FrameProgram on modelled queues, links and host threads.

- Each queue is one process that runs its tasks in submission order, one at a time, waiting
  for each task's dependencies first (a Vulkan queue with semaphore waits behaves so).
- Copies hold their queue and cross a fluid :class:`Channel` (PCIe direction, peer link).
- Host copies are dispatched in order by the host thread, split into parts of at least
  `chunk_min_bytes` over the memcpy thread pool, each part a flow on host memory bandwidth
  capped at one thread's speed.
Dependencies are counted, not stored as events per task, so memory stays flat over 10^5 frames.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Iterator

import numpy as np
import simpy

from ..costs import CostModel
from ..errors import ScheduleError
from ..schedules.base import FrameProgram
from ..tasks import CopyTask, HostCopyTask, PassTask, QueueRef, Task
from .channel import Channel

Key = tuple[int, str]


@dataclass
class RawResult:
    """What the engine observed; :mod:`mgpusim.results` turns it into tables."""

    rows: list[tuple]
    frame_start: np.ndarray
    present_end: np.ndarray
    channels: dict[str, Channel]
    skipped: dict[str, int] = field(default_factory=dict)
    effects: dict[str, bool] = field(default_factory=dict)
    #: frames in which each skippable task was skipped (for update rates in steady state)
    skipped_frames: dict[str, list[int]] = field(default_factory=dict)


class Engine:
    def __init__(self, program: FrameProgram, costs: CostModel, record_trace: bool = True):
        self.program, self.costs, self.record = program, costs, record_trace
        self.env = simpy.Environment()
        self.period = len(program.templates)
        self.rows: list[tuple] = []
        self.frame_start = np.full(program.frames, np.iinfo(np.int64).max, dtype=np.int64)
        self.present_end = np.full(program.frames, -1, dtype=np.int64)
        self._pending: dict[Key, int] = {}
        self._waiters: dict[Key, simpy.Event] = {}
        self._ready: set[Key] = set()
        self._skip: set[Key] = set()
        self._inflight: dict[str, int] = defaultdict(int)
        self._skipped: dict[str, int] = defaultdict(int)
        self._skipped_frames: dict[str, list[int]] = defaultdict(list)
        self._index = [{t.name: t for t in tasks} for tasks in program.templates]
        self._skip_groups()
        self._dependents = self._reverse_deps()
        self._waits_for = self._waits_for_labels()
        self._durations: dict[tuple[int, str], int] = {}
        self.channels: dict[str, Channel] = {}
        self._unfinished = sum(len(program.tasks(f)) for f in range(program.frames))
        self._setup_resources()

    # ----- build -------------------------------------------------------------------------
    def _reverse_deps(self) -> list[dict[str, list[tuple[str, int]]]]:
        """dependents[phase][name] = [(dependent task, frame distance k >= 0)]."""
        out: list[dict[str, list[tuple[str, int]]]] = [defaultdict(list) for _ in range(self.period)]
        for q, tasks in enumerate(self.program.templates):
            for task in tasks:
                for dep in task.deps:
                    k = -dep.offset
                    out[(q - k) % self.period][dep.task].append((task.name, k))
        return out

    def _waits_for_labels(self) -> list[dict[str, str]]:
        """Per task, the dependencies on other devices or frames, as 'offset:task' labels."""
        labels: list[dict[str, str]] = []
        for phase, tasks in enumerate(self.program.templates):
            here: dict[str, str] = {}
            for task in tasks:
                dev = _device(task)
                parts = []
                for d in task.deps:
                    other = self._index[(phase + d.offset) % self.period][d.task]
                    if d.offset or _device(other) != dev:
                        parts.append(f"{d.offset}:{d.task}")
                here[task.name] = ";".join(parts)
            labels.append(here)
        return labels

    def _setup_resources(self) -> None:
        queues: dict[QueueRef, list[list[Task]]] = {}
        host_tasks: list[list[Task]] = [[] for _ in range(self.period)]
        for phase, tasks in enumerate(self.program.templates):
            for task in tasks:
                self._durations[(phase, task.name)] = self._duration(task)
                if isinstance(task, HostCopyTask):
                    host_tasks[phase].append(task)
                    continue
                plan = queues.setdefault(task.queue, [[] for _ in range(self.period)])
                plan[phase].append(task)
                if isinstance(task, CopyTask):
                    self._channel_for(task)
        for qref, plan in queues.items():
            self.env.process(self._queue_proc(qref, plan))
        if any(host_tasks):
            host = self.costs.profile.host
            self.threads = simpy.Store(self.env, capacity=host.memcpy_threads)
            self.threads.items.extend(range(host.memcpy_threads))
            self.channels["host.memory"] = Channel(self.env, "host.memory", self.costs.host_memory_bandwidth())
            self.env.process(self._host_proc(host_tasks))

    def _duration(self, task: Task) -> int:
        if isinstance(task, PassTask):
            return self.costs.pass_ns(task.queue.device, task.kind, task.work)
        if isinstance(task, CopyTask):
            return self.costs.copy_setup_ns(task.queue.device, task.queue.family, task.path, task.peer)
        return self.costs.profile.host.host_copy_fixed_ns

    def _channel_for(self, task: CopyTask) -> Channel:
        dev = task.queue.device
        if task.path == "p2p":
            if task.peer is None:
                raise ScheduleError(f"copy {task.name!r} on a peer path names no peer")
            name, bw = f"peer{dev}-{task.peer}", self.costs.peer_bandwidth(dev, task.peer)
        else:
            name, bw = f"gpu{dev}.{task.path}", self.costs.link_bandwidth(dev, task.path)
        if name not in self.channels:
            self.channels[name] = Channel(self.env, name, bw)
        return self.channels[name]

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
        if self._initial(key[0], task) == 0:
            self._mark_ready(key, task)
            return True
        self._pending[key] = self._initial(key[0], task)
        return False

    # ----- skippable chains ("new wait") ------------------------------------------------
    def _skip_groups(self) -> None:
        """Group skippable tasks into chains. A skip_if_busy task with a same-frame dependency
        on another skip_if_busy task is a *follower* (it consumes that task's output, e.g. the
        copies of a particle update); one without is a *leader*. A leader is skipped when any
        task of its chain from an earlier frame is still unfinished; a follower is skipped
        exactly when one of its skippable inputs of the same frame was skipped."""
        self._inputs: list[dict[str, tuple[str, ...]]] = []
        self._leader: list[dict[str, str]] = []
        self._chain: list[dict[str, int]] = []
        self._readers: list[dict[str, int]] = []
        for phase, tasks in enumerate(self.program.templates):
            idx = self._index[phase]
            inputs, leader, chain, readers = {}, {}, defaultdict(int), defaultdict(int)
            for task in tasks:
                if not task.skip_if_busy:
                    continue
                ins = tuple(d.task for d in task.deps if d.offset == 0 and idx[d.task].skip_if_busy)
                leader[task.name] = leader[ins[0]] if ins else task.name
                chain[leader[task.name]] += 1
                for n in ins:
                    readers[n] += 1
                if ins:
                    inputs[task.name] = ins
            self._inputs.append(inputs)
            self._leader.append(leader)
            self._chain.append(dict(chain))
            self._readers.append(dict(readers))
        self._skipped_keys: dict[Key, int] = {}  # skipped key -> followers yet to look at it

    def _mark_ready(self, key: Key, task: Task) -> None:
        if not task.skip_if_busy:
            return
        phase = key[0] % self.period
        ins = self._inputs[phase].get(task.name)
        if ins is not None:
            if self._take_skipped(key[0], ins):
                self._set_skipped(key, phase, task.name)
        elif self._inflight[task.name] > 0:
            self._set_skipped(key, phase, task.name)
        else:
            self._inflight[task.name] += self._chain[phase][task.name]

    def _take_skipped(self, frame: int, inputs: tuple[str, ...]) -> bool:
        skipped = False
        for name in inputs:
            left = self._skipped_keys.get((frame, name))
            if left is None:
                continue
            skipped = True
            if left <= 1:
                del self._skipped_keys[(frame, name)]
            else:
                self._skipped_keys[(frame, name)] = left - 1
        return skipped

    def _set_skipped(self, key: Key, phase: int, name: str) -> None:
        self._skip.add(key)
        self._skipped_frames[name].append(key[0])
        if self._readers[phase].get(name):
            self._skipped_keys[key] = self._readers[phase][name]

    def _complete(self, frame: int, task: Task, skipped: bool = False) -> None:
        self._unfinished -= 1
        if not skipped and task.skip_if_busy:
            self._inflight[self._leader[frame % self.period][task.name]] -= 1
        frames = self.program.frames
        for name, k in self._dependents[frame % self.period].get(task.name, ()):
            g = frame + k
            if g >= frames:
                continue
            key = (g, name)
            dtask = self._index[g % self.period][name]
            left = self._pending.get(key)
            if left is None:
                left = self._initial(g, dtask)
            left -= 1
            if left:
                self._pending[key] = left
                continue
            self._pending.pop(key, None)
            self._mark_ready(key, dtask)
            waiter = self._waiters.pop(key, None)
            if waiter is not None:
                waiter.succeed()
            else:
                self._ready.add(key)

    def _wait(self, frame: int, task: Task) -> Iterator[simpy.Event]:
        key = (frame, task.name)
        if not self._check_ready(key, task):
            ev = self.env.event()
            self._waiters[key] = ev
            yield ev

    # ----- processes ---------------------------------------------------------------------
    def _queue_proc(self, qref: QueueRef, plan: list[list[Task]]):
        env, period = self.env, self.period
        dev, engine = qref.device_name, qref.engine
        for frame in range(self.program.frames):
            phase = frame % period
            for task in plan[phase]:
                yield from self._wait(frame, task)
                key = (frame, task.name)
                if key in self._skip:
                    self._skip.discard(key)
                    self._skipped[task.name] += 1
                    self._complete(frame, task, skipped=True)
                    continue
                start = env.now
                yield env.timeout(self._durations[(phase, task.name)])
                nbytes = 0
                if isinstance(task, CopyTask):
                    nbytes = task.bytes
                    cap = self.costs.copy_cap(task.queue.device, task.queue.family, task.path)
                    yield self._channel_for(task).transfer(nbytes, cap)
                self._finish(frame, task, dev, engine, start, nbytes)

    def _finish(self, frame: int, task: Task, dev: str, engine: str, start: int, nbytes: int) -> None:
        end = self.env.now
        if start < self.frame_start[frame]:
            self.frame_start[frame] = start
        if task.name == self.program.present_task:
            self.present_end[frame] = end
        if self.record:
            self.rows.append((frame, dev, engine, task.step, task.name, start, end, nbytes,
                              self._waits_for[frame % self.period][task.name]))
        self._complete(frame, task)

    def _host_proc(self, plan: list[list[Task]]):
        """The host thread: dispatches host copies in order once their inputs are ready."""
        for frame in range(self.program.frames):
            for task in plan[frame % self.period]:
                yield from self._wait(frame, task)
                key = (frame, task.name)
                if key in self._skip:
                    self._skip.discard(key)
                    self._skipped[task.name] += 1
                    self._complete(frame, task, skipped=True)
                    continue
                self._dispatch_host_copy(frame, task)  # type: ignore[arg-type]

    def _dispatch_host_copy(self, frame: int, task: HostCopyTask) -> None:
        threads = self.costs.profile.host.memcpy_threads
        parts = max(1, min(threads, task.bytes // task.chunk_min_bytes))
        base = task.bytes // parts
        sizes = [base] * (parts - 1) + [task.bytes - base * (parts - 1)]
        state = {"left": parts}
        for size in sizes:
            self.env.process(self._host_part(frame, task, size, state))

    def _host_part(self, frame: int, task: HostCopyTask, size: int, state: dict):
        tid = yield self.threads.get()
        start = self.env.now
        fixed = self._durations[(frame % self.period, task.name)]
        if fixed:
            yield self.env.timeout(fixed)
        yield self.channels["host.memory"].transfer(size, self.costs.memcpy_thread_cap())
        self.threads.put(tid)
        state["left"] -= 1
        last = state["left"] == 0
        end = self.env.now
        if start < self.frame_start[frame]:
            self.frame_start[frame] = start
        if self.record:
            self.rows.append((frame, "host", f"thread{tid}", task.step, task.name, start, end, size,
                              self._waits_for[frame % self.period][task.name]))
        if last:
            self._complete(frame, task)

    # ----- run ---------------------------------------------------------------------------
    def run(self) -> RawResult:
        self.env.run()
        if self._unfinished:
            raise ScheduleError(self._blocked_message())
        effects = {
            "link_model": any(not n.startswith("host.") for n in self.channels),
            "link_contention": any(c.max_concurrent > 1 for n, c in self.channels.items() if n != "host.memory"),
            "host_copies": "host.memory" in self.channels,
            "host_memory_contention": self.channels.get("host.memory", None) is not None
            and self.channels["host.memory"].max_concurrent > 1,
        }
        return RawResult(self.rows, self.frame_start, self.present_end, self.channels,
                         dict(self._skipped), effects, dict(self._skipped_frames))

    def _blocked_message(self) -> str:
        blocked = sorted(self._waiters)[:8]
        names = ", ".join(f"frame {f} {n}" for f, n in blocked)
        return (f"schedule {self.program.schedule!r} cannot finish: {self._unfinished} task(s) never "
                f"ran; blocked waiting on dependencies: {names or 'none (a queue is stuck)'}")


def _device(task: Task) -> str:
    return "host" if isinstance(task, HostCopyTask) else task.queue.device_name
