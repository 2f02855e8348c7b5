"""Task builders: what running one task of a program means, worked out once per task (its :class:`Op`).

Why a module of its own: three levels need the same rules for a task's duration, the channel its
bytes cross and at what rate, and the labels of its trace row. The event engine (:mod:`.engine`)
runs the ops; the analytic level (:mod:`.analytic`) reads durations, rates and labels off them
without building an engine; the replay (:mod:`.replay`, through the engine) gives measured
durations in place of the costs. One :class:`OpBuilder` for all three keeps them from drifting
apart, and keeps the engine to running the timeline.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from functools import partial
from typing import Callable, Mapping, Union

import simpy

from mgpusim.model.costs import CostModel, gbps_fraction
from mgpusim.model.errors import ScheduleError
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, PassTask, Task
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.task_inputs import TaskInputs, task_inputs
from mgpusim.sim.busy_wake import BusyWake
from mgpusim.sim.channel import Channel, FixedRateChannel
from mgpusim.sim.executors import Executor, Runner
from mgpusim.sim.hostlink import HostLinkChannel, LinkPort
from mgpusim.sim.snapshot import Environment

#: (frame or frame phase, task name)
Key = tuple[int, str]
#: What a copy's bytes cross: a link direction (shared or at a fixed rate), or one GPU's link of
#: the host side of PCIe.
LinkChannel = Union[Channel, FixedRateChannel, LinkPort]
#: A channel of the run, as the engine's results list them: link directions, the host side of
#: PCIe, host memory, and the cores or GPUs that executors share (Channel and its GpuChannel).
RunChannel = Union[Channel, FixedRateChannel, HostLinkChannel]


@dataclass(frozen=True, slots=True, eq=False)
class Op:
    """Everything the engine's hot loop needs about one task, computed once (a slotted
    dataclass: each field is one attribute read per task)."""

    task: Task
    duration: int
    channel: LinkChannel | None
    cap: Fraction | None
    nbytes: int
    device: str
    engine: str
    #: the task's id in the program's TaskInputs (its listed inputs), logged with every row
    waits_for: int
    is_present: bool
    #: What the executor makes of the task's work: `run(amount)` is the event to wait for
    #: (None: no work to wait for).
    run: Runner | None = None
    amount: int = 0
    #: The queue's idle time before the task (the GPU's task_gap_ns), on the host's executor.
    gap: int = 0
    gap_run: Runner | None = None
    #: a CPU task: its thread wakes `dispatch_ns` after an input from elsewhere, no submit cost
    cpu: bool = False
    #: a pass that keeps every host core busy (the busy_wake effect): the cores it keeps busy
    fill_cores: Fraction | None = None
    #: the duration is a measured one (the replay level): a copy or host-copy part spends
    #: exactly `duration`, crossing no channel
    measured: bool = False
    #: the task's name (read in the hot loop)
    name: str = ""
    #: its entry of the engine's dependents table (set by the engine once the op is built)
    dependents: list = field(default_factory=list)
    #: `cross()` is the event of its bytes crossing `channel` (None without a channel): the
    #: transfer with its arguments bound, its time worked out once where it is fixed
    cross: Callable[[], simpy.Event] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", self.task.name)
        if self.channel is not None:
            object.__setattr__(self, "cross", crossing(self.channel, self.nbytes, self.cap))


def crossing(channel: LinkChannel, nbytes: int, cap: Fraction | None) -> Callable[[], simpy.Event]:
    """A transfer of `nbytes` at `cap` on `channel`, ready to start: on a fixed-rate channel
    its time does not depend on what else crosses, so it is worked out here, not per frame."""
    if isinstance(channel, FixedRateChannel) and nbytes > 0:
        return partial(channel.cross, channel.duration(nbytes, cap))
    return partial(channel.transfer, nbytes, cap)


def channel_name(task: CopyTask) -> str:
    """The link direction a copy crosses: its GPU's `gpu<i>.<path>`, or `peer<i>-<j>`."""
    dev = task.queue.device
    if task.path in ("p2p", "group"):
        if task.peer is None:
            raise ScheduleError(f"copy {task.name!r} on a peer path names no peer")
        return f"peer{dev}-{task.peer}"
    return f"gpu{dev}.{task.path}"


class OpBuilder:
    """Turns a program's tasks into :class:`Op` s, with what decides them: the cost model, the
    effects modelled, measured durations where given (the replay), the executors of the devices
    and the host, and the channels the copies cross (made as the first copy needs each, in
    `channels`, which also lists the channels of executors that devices share).

    The engine runs the ops it builds. The analytic level builds them on an environment it
    never runs, with channels that exist only to say their bandwidth, for the durations, rates
    and labels of its recurrence."""

    def __init__(self, program: FrameProgram, costs: CostModel, effects: frozenset[str],
                 env: Environment, executors: Mapping[str, Executor],
                 durations: Mapping[Key, int] | None = None, busy_wake: BusyWake | None = None,
                 inputs: TaskInputs | None = None):
        """`durations`: (frame phase, task name) -> ns the task takes there instead of its
        cost (see :meth:`measured_op`). `busy_wake`: the busy_wake effect's state (None: off),
        which says which passes keep every host core busy. `inputs`: `task_inputs(program)`
        where the caller has it already (a model retimed on other links)."""
        self.program, self.costs, self.effects, self.env = program, costs, effects, env
        self.executors = executors
        self._durations = durations or {}
        self._busy_wake = busy_wake
        #: every task's id and the inputs its trace row lists; rows log the id
        self.inputs: TaskInputs = inputs if inputs is not None else task_inputs(program)
        self._waits_for = self.inputs.ids
        self.channels: dict[str, RunChannel] = {}
        for ex in dict.fromkeys(executors.values()):  # a shared pool is one channel
            if ex.shared:
                assert ex.channel is not None, "a shared executor names its channel"
                self.channels[ex.channel.name] = ex.channel

    def all_ops(self) -> list[list[Op]]:
        """Every task's op, per frame phase, in the program's order (channels are made in
        that order, so the run lists them so)."""
        return [[self.op(phase, task) for task in tasks] for phase, tasks in enumerate(self.program.templates)]

    def op(self, phase: int, task: Task) -> Op:
        """Everything the hot loop needs about one task, computed once."""
        measured = self._durations.get((phase, task.name))
        if measured is not None:
            return self.measured_op(phase, task, measured)
        channel: LinkChannel | None = None
        cap: Fraction | None = None
        nbytes = 0
        duration = self.duration(task)
        gap, gap_run = 0, None
        if isinstance(task, HostCopyTask):
            host_cap = self.costs.host_copy_cap(task, "uncached_reads" in self.effects)
            rate, rate_field = self.host_copy_bound(host_cap)
            self.costs.check_transfer(task.name, task.bytes, rate, duration, rate_field)
            return Op(task, duration, None, host_cap, 0, "host", "memcpy", self._waits_for[phase][task.name],
                      task.name == self.program.present_task)
        if isinstance(task, CpuTask):  # one host thread's time (a core's, on emulated GPUs)
            run, amount = self.cpu_runner(task, duration)
            return Op(task, duration, None, None, 0, "host", task.thread,
                      self._waits_for[phase][task.name], task.name == self.program.present_task,
                      run, amount, cpu=True)
        executor = self.executors[task.queue.device_name]
        if isinstance(task, CopyTask):
            nbytes = task.bytes
            full_cap = self.costs.copy_cap(task.queue.device, task.queue.family, task.path)
            self.check_copy_time(task, full_cap, duration)
            cap = full_cap if "copy_engine_caps" in self.effects else None
            if executor.copies_on_cores:  # a memcpy in the queue's thread / its GPU's work
                bw = self.path_bandwidth(task)
                rate = bw if cap is None else min(cap, bw)
                duration += -(-nbytes * rate.denominator // rate.numerator)
                cap = None
            else:
                channel = self.channel_for(task)
        if "task_gaps" in self.effects:
            gap = self.costs.profile.gpus[task.queue.device].task_gap_ns
            if gap:
                gap_run = executor.work
        run, amount = executor.task_runner(task, duration)
        fills = None
        if self._busy_wake is not None and isinstance(task, PassTask):
            cores = executor.cores(task)
            fills = cores if self._busy_wake.fills(cores, duration) else None
        return Op(task, duration, channel, cap, nbytes, task.queue.device_name, task.queue.engine,
                  self._waits_for[phase][task.name], task.name == self.program.present_task,
                  run, amount, gap, gap_run, fill_cores=fills)

    def host_copy_bound(self, cap: Fraction) -> tuple[Fraction, str]:
        """The slowest rate a host copy can cross at alone, and the profile field that sets
        it, for the per-task time bound: a part's cap (a memcpy thread, or uncached reads),
        or host memory where it is slower and the copy goes through it (not where memcpys are
        work on the shared cores). Why: a copy slowed by host memory alone must be bounded
        like any other task, else its end leaves int64 ns."""
        if not self.executors["host"].copies_on_cores:
            memory = self.costs.host_memory_bandwidth()
            if memory < cap:
                return memory, "host.memory_bandwidth_gbps"
        return cap, ("host.uncached_read_gbps" if cap < self.costs.memcpy_thread_cap()
                     else "host.memcpy_thread_gbps")

    def measured_op(self, phase: int, task: Task, duration: int) -> Op:
        """A task that takes the given `duration` (ns) on its queue, thread or memcpy threads,
        whatever else runs: no channel, cap or shared executor stretches it. The idle gap and
        host hand-offs before it stay the model's."""
        waits, present = self._waits_for[phase][task.name], task.name == self.program.present_task
        if isinstance(task, HostCopyTask):  # each part: one memcpy thread's core for its time
            run, amount = self.executors["host"].runner(duration, 1)
            return Op(task, duration, None, None, 0, "host", "memcpy", waits, present, run, amount,
                      measured=True)
        if isinstance(task, CpuTask):
            run, amount = self.cpu_runner(task, duration)
            return Op(task, duration, None, None, 0, "host", task.thread, waits, present, run, amount,
                      cpu=True, measured=True)
        executor = self.executors[task.queue.device_name]
        gap = self.costs.profile.gpus[task.queue.device].task_gap_ns if "task_gaps" in self.effects else 0
        run, amount = executor.task_runner(task, duration)
        nbytes = task.bytes if isinstance(task, CopyTask) else 0
        fills = None
        if self._busy_wake is not None and isinstance(task, PassTask):
            cores = executor.cores(task)
            fills = cores if self._busy_wake.fills(cores, duration) else None
        return Op(task, duration, None, None, nbytes, task.queue.device_name, task.queue.engine, waits,
                  present, run, amount, gap, executor.work if gap else None, fill_cores=fills,
                  measured=True)

    def cpu_runner(self, task: CpuTask, duration: int) -> tuple[Runner | None, int]:
        """A CPU task's time on a host core (shared with the GPUs' passes on CPU-emulated GPUs),
        or, for a thread that sleeps (`idle`), plain time."""
        if task.idle:
            return (self.env.timeout, duration) if duration else (None, 0)
        return self.executors["host"].runner(duration, 1)

    def duration(self, task: Task) -> int:
        """The task's cost in ns: a pass's time, a copy's setup, a CPU task's work, a host
        copy's fixed cost per part (bytes crossing a channel come on top)."""
        if isinstance(task, PassTask):
            return self.costs.pass_ns(task.queue.device, task.kind, task.work)
        if isinstance(task, CopyTask):
            return self.costs.copy_setup_ns(task.queue.device, task.queue.family, task.path, task.peer)
        if isinstance(task, CpuTask):
            return self.costs.cpu_task_ns(task, "host_frame_work" in self.effects)
        return self.costs.profile.host.host_copy_fixed_ns

    def path_bandwidth(self, task: CopyTask) -> Fraction:
        """The bandwidth of the link a copy crosses, alone on it."""
        dev = task.queue.device
        if task.path == "p2p":
            if task.peer is None:  # (refused as its channel's name refuses it)
                raise ScheduleError(f"copy {task.name!r} on a peer path names no peer")
            return self.costs.peer_bandwidth(dev, task.peer)
        if task.path == "group":
            return self.costs.group_bandwidth(*task.ends())
        return self.costs.link_bandwidth(dev, task.path)

    def check_copy_time(self, task: CopyTask, cap: Fraction | None, setup: int) -> None:
        """A copy alone on its path must end within the bound on one task's time."""
        bw, dev = self.path_bandwidth(task), task.queue.device
        where = {"p2p": "peer_links", "d2d": f"gpus[{dev}].local_copy_gbps",
                 "group": f"gpus[{task.ends()[0]}].link.d2h_gbps"}.get(
            task.path, f"gpus[{dev}].link.{task.path}_gbps")
        if cap is not None and cap < bw:
            bw, where = cap, f"gpus[{dev}].copy.{task.queue.family}.{task.path}_gbps"
        self.costs.check_transfer(task.name, task.bytes, bw, setup, where)

    def channel_for(self, task: CopyTask) -> LinkChannel:
        """The channel a copy's bytes cross, made the first time a copy needs it: its link
        direction, shared (link_sharing) or at a fixed rate; under host_pcie its GPU's link of
        the host side of PCIe of that direction."""
        host_gbps = self.costs.profile.host.pcie_gbps(task.path) if "host_pcie" in self.effects else None
        if host_gbps:  # the GPU's link and the host side of PCIe, shared by every GPU's copies
            shared = f"pcie.{task.path}"
            host = self.channels.get(shared)
            if host is None:
                host = self.channels[shared] = HostLinkChannel(self.env, shared, gbps_fraction(host_gbps))
            assert isinstance(host, HostLinkChannel)
            return host.port(channel_name(task), self.path_bandwidth(task))
        name = channel_name(task)
        link = self.channels.get(name)
        if link is None:
            kind = Channel if "link_sharing" in self.effects else FixedRateChannel
            link = self.channels[name] = kind(self.env, name, self.path_bandwidth(task))
        assert not isinstance(link, HostLinkChannel), f"{name} is a link direction"
        return link

    def host_memory(self) -> Channel | FixedRateChannel:
        """The host memory channel the parts of host copies cross (made once, on first use):
        shared (host_memory_sharing) or at a fixed rate."""
        memory = self.channels.get("host.memory")
        if memory is None:
            kind = Channel if "host_memory_sharing" in self.effects else FixedRateChannel
            memory = self.channels["host.memory"] = kind(self.env, "host.memory", self.costs.host_memory_bandwidth())
        assert not isinstance(memory, HostLinkChannel)
        return memory
