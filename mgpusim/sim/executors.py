"""Executors: what runs a device's work. The engine is given one per device and the host.

A real GPU runs its own work: a pass of `ns` is a delay of `ns` (:class:`Dedicated`). GPUs
emulated on the host CPU (lavapipe) share its cores with each other, the memcpy threads and the
submit threads (:class:`SharedCores`): a pass of `ns` that keeps `cores` busy is `ns x cores`
core-ns of work on one fluid channel of the host's cores, so passes that overlap slow each other.
The queues of one real GPU share it too (:class:`SharedGpu`, the shared_gpu effect): a pass
on the compute queue slows a render on the graphics queue, by how much the profile's overlap
efficiency of that pair of queues says; so do several logical GPUs (VkDevices) on one physical
GPU. The engine never asks which kind it has: it asks the executor for a *runner* once per task
when it builds, and yields what the runner returns in its hot loop.
"""
from __future__ import annotations

from fractions import Fraction
from typing import Callable, Protocol

import simpy

from mgpusim.model.costs import CostModel
from mgpusim.model.profile import QUEUE_FAMILIES, HardwareProfile
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, PassTask, QueueRef, Task
from mgpusim.schedules.base import FrameProgram
from mgpusim.sim.channel import Channel, GpuChannel, PassWork
from mgpusim.sim.snapshot import Environment

#: A runner: called with an amount, returns the event that fires when that work is done.
Runner = Callable[[int], simpy.Event]
#: One thread's cap on a pool of cores (or on the interpreter): one core. A Fraction, as every
#: cap a channel takes, and one object for all such work (a channel compares caps by identity
#: before it compares them by value).
ONE_CORE = Fraction(1)


class Dedicated:
    """A device with its own cores: work of `ns` takes `ns`, whatever else runs."""

    shared = False
    #: a copy crosses a link channel (a real copy engine), not the device's own cores
    copies_on_cores = False
    #: host threads waking on inputs take turns (see SharedCores); a real GPU's host has the
    #: cores to wake them at once, and its calibrated `dispatch_ns` holds what they wait for
    serial_dispatch = False
    #: the channel of the cores it shares with other devices or threads: none, its own cores
    channel: Channel | None = None

    def __init__(self, env: Environment):
        self.env = env

    def runner(self, ns: int, cores: Fraction | int = 1) -> tuple[Runner | None, int]:
        """(runner, amount) for work of `ns`; no runner for no work (nothing to wait for)."""
        return (self.env.timeout, ns) if ns else (None, 0)

    def task_runner(self, task: Task, ns: int) -> tuple[Runner | None, int]:
        """(runner, amount) for `task`'s work of `ns`."""
        return self.runner(ns, self.cores(task))

    def work(self, ns: int) -> simpy.Event:
        """One thread's `ns` of time (a host thread waking, a queue's idle gap)."""
        return self.env.timeout(ns)

    def background(self) -> Callable[[int], object] | None:
        """Work that delays nobody by itself (a submit thread's): nothing to model here."""
        return None

    def cores(self, task: Task) -> Fraction:
        return Fraction(1)


class SharedCores:
    """Devices emulated on a pool of host cores (`host.cpu`): all their work is core-time on one
    fluid channel of `cpu_cores`, capped per task at the cores it keeps busy."""

    shared = True
    #: a copy is a memcpy in the queue's thread: one core's work
    copies_on_cores = True
    #: the runner's submit threads wake and submit in Python, one at a time (the interpreter
    #: lock): with 3-4 lavapipe GPUs on two cores, the secondaries woken by one present start
    #: their frames 0.4-1.5 ms apart, one after another, not together
    serial_dispatch = True

    def __init__(self, env: Environment, costs: CostModel):
        host = costs.profile.host
        self.costs = costs
        cores = Fraction(host.cpu_cores)
        eff = Fraction(repr(host.oversubscribed_efficiency))
        self.channel = Channel(env, "host.cpu", cores, cores * eff if eff != 1 else None)
        #: each task's (cores, tag, overhead), by identity (a run builds an op per task and
        #: frame of its period: a replay one per measured frame)
        self._of_task: dict[int, tuple[Task, Fraction, object, int]] = {}

    def runner(self, ns: int, cores: Fraction | int = 1, tag: object = None) -> tuple[Runner | None, int]:
        cores = cores if type(cores) is Fraction else Fraction(cores)  # (the task's own: a cache hit)
        transfer = self.channel.transfer

        def run(amount: int) -> simpy.Event:
            return transfer(amount, cores, tag)
        return run, -(-ns * cores.numerator // cores.denominator)

    def task_runner(self, task: Task, ns: int) -> tuple[Runner | None, int]:
        """The task's work at its cores; a pass with a `cpu_overhead_ns` also puts that much
        of one core's work on the pool when it starts, which nobody waits on."""
        _task, cores, tag, overhead = self._task_terms(task)
        run, amount = self.runner(ns, cores, tag)
        if not overhead or run is None:
            return run, amount
        transfer, main = self.channel.transfer, run

        def with_overhead(amount: int) -> simpy.Event:
            transfer(overhead, ONE_CORE)
            return main(amount)
        return with_overhead, amount

    def _task_terms(self, task: Task) -> tuple[Task, Fraction, object, int]:
        """The task's cores, sharing tag and driver overhead, worked out once per task."""
        found = self._of_task.get(id(task))
        if found is None or found[0] is not task:
            found = self._of_task[id(task)] = (task, task_cores(self.costs.profile, task),
                                               self._tag(task), self._overhead(task))
        return found

    def _tag(self, task: Task) -> object:
        """What the cores share: a pass's kind (lossless where its cores were measured two at
        once: they say how it shares the cores), else nothing (a copy, a host thread)."""
        if isinstance(task, PassTask):
            cost = self.costs.profile.gpus[task.queue.device].costs.get(task.kind)
            return PassWork(task.kind, cost is not None and cost.cores_from_pairs)
        return None

    def _overhead(self, task: Task) -> int:
        if not isinstance(task, PassTask):
            return 0
        cost = self.costs.profile.gpus[task.queue.device].costs.get(task.kind)
        scale = self.costs.profile.host.cpu_overhead_scale
        return int(round(cost.cpu_overhead_ns * scale)) if cost is not None else 0

    def work(self, ns: int) -> simpy.Event:
        """One thread's `ns` of time: one core's work on the pool."""
        return self.channel.transfer(ns, ONE_CORE)

    def background(self) -> Callable[[int], object] | None:
        """One core's work for `ns` that nobody waits on (a submit thread recording commands)."""
        return lambda ns: self.channel.transfer(ns, ONE_CORE)

    def cores(self, task: Task) -> Fraction:
        """Cores a task keeps busy (see `task_cores`)."""
        return self._task_terms(task)[1]


class MeasuredCores(SharedCores):
    """The host's cores under work whose time was measured (the replay level): a pass or copy
    takes exactly its time and meanwhile occupies the cores it keeps busy, so that the host
    threads' own work (waking on an input, submitting) is slowed by it as on the real machine;
    that work alone is costed by the pool. Why: on CPU-emulated GPUs a submit thread wakes
    behind the GPUs' threads, which a replay on idle cores would miss. A pass's driver
    overhead (`cpu_overhead_ns`) still goes on the pool beside it (the inherited task_runner)."""

    def runner(self, ns: int, cores: Fraction | int = 1, tag: object = None) -> tuple[Runner | None, int]:
        if not ns:
            return None, 0
        channel, env = self.channel, self.channel.env
        share = cores if type(cores) is Fraction else Fraction(cores)

        def run(amount: int) -> simpy.Event:
            held = channel.occupy(share, tag)
            done = env.timeout(amount)
            done.callbacks.append(lambda _event: channel.release(held))
            return done
        return run, ns


class Interpreter(Dedicated):
    """The host of GPUs with their own cores, driven by threads that share one Python
    interpreter (`host.shared_interpreter`): a thread's wake-up work (`dispatch_ns`) and each
    task's submit work (`submit_ns`) are time on one channel of one core, shared by all that
    want it at once. Why a shared channel and not turns: the interpreter lock is handed over
    every switch interval (0.2 ms in the runner), so threads that run Python together each
    progress at a share of it. CPU tasks and host copies keep their own threads (a memcpy
    runs without the lock)."""

    shared = True
    channel: Channel

    def __init__(self, env: Environment):
        super().__init__(env)
        self.channel = Channel(env, "host.interpreter", Fraction(1))

    def work(self, ns: int) -> simpy.Event:
        """A woken thread's `ns` of Python, at its share of the interpreter."""
        return self.channel.transfer(ns, ONE_CORE)

    def background(self) -> Callable[[int], object] | None:
        """A task's submit work on the interpreter, which nobody waits on but everyone
        shares it with: the same work as a woken thread's."""
        return self.work


class SharedGpu(Dedicated):
    """One physical GPU whose queues (of one or several logical GPUs) share its execution
    throughput: every pass and copy of its queues is work on one :class:`GpuChannel`. Alone a
    piece of work runs at full speed; two at once run at together `e` times the speed of one
    (`e`: the pair's overlap efficiency, :func:`pair_efficiency`), each at half of that.

    A copy is work of its queue at its rate alone (link or copy-engine rate): a copy on a copy
    engine (transfer queue) is another unit, and shares only what `graphics_transfer` /
    `compute_transfer` say (memory bandwidth); a copy on the graphics queue is graphics work.
    Its link is not a channel of its own then: the pair efficiencies replace link sharing
    between this GPU's queues."""

    shared = True
    copies_on_cores = True
    channel: GpuChannel

    def __init__(self, env: Environment, profile: HardwareProfile, physical: int):
        super().__init__(env)
        self.profile = profile
        self.channel = GpuChannel(env, f"gpu{physical}.exec", lambda tags: shares(profile, tags))

    def task_runner(self, task: Task, ns: int) -> tuple[Runner | None, int]:
        if not ns:
            return None, 0
        transfer, tag = self.channel.transfer, work_tag(task)
        return (lambda amount: transfer(amount, None, tag)), ns


#: What a piece of work on a shared GPU is, for its overlap efficiencies: its queue and its
#: pass kind ("copy" for a copy).
WorkTag = tuple[QueueRef, str]


def task_cores(profile: HardwareProfile, task: Task) -> Fraction:
    """Cores a task of CPU-emulated GPUs keeps busy: a copy or a CPU task its thread, a pass its
    kind's measured `cores` (with `term_cores`, weighted by its work's terms), else the GPU's
    rasterizer threads (never more than the host's cores)."""
    host = profile.host
    if isinstance(task, (CopyTask, HostCopyTask, CpuTask)):
        return Fraction(1)
    gpu = profile.gpus[task.queue.device]
    threads = Fraction(min(gpu.cpu_threads or host.cpu_cores, host.cpu_cores))
    cost = gpu.costs.get(task.kind) if isinstance(task, PassTask) else None
    cores = None if cost is None else cost.cores_of(task.work)
    if cores is None:
        return threads
    return min(Fraction(repr(cores)).limit_denominator(1000), threads)


def work_tag(task: Task) -> WorkTag:
    return task.queue, task.kind if isinstance(task, PassTask) else "copy"  # type: ignore[union-attr]


def pair_efficiency(profile: HardwareProfile, a: WorkTag, b: WorkTag) -> float:
    """Overlap efficiency of work `a` and `b` on queues of one physical GPU: passes of two
    logical GPUs take `devices` (a copy engine is shared across them by its family pair), two
    queues of one family `same_family`, else the families' pair (graphics_compute, ...); a pass
    kind's own table (`queue_overlap.<kind>`) wins over the GPU's."""
    (qa, ka), (qb, kb) = a, b
    gpu = profile.gpus[qa.device]
    if qa.device != qb.device and "transfer" not in (qa.family, qb.family):
        pair = "devices"
    elif qa.family == qb.family:
        pair = "same_family"
    else:
        pair = "_".join(sorted((qa.family, qb.family), key=QUEUE_FAMILIES.index))
    return gpu.overlap(pair, (ka, kb))


def shares(profile: HardwareProfile, tags: tuple[WorkTag, ...]) -> tuple[Fraction, ...]:
    """Each piece's speed, in units of its speed alone, while the pieces `tags` run at once on
    one physical GPU.

    Why classes: pieces whose pair efficiency is at most 1 contend for one unit (two VkDevices'
    contexts, which the GPU time-slices; two queues that gain nothing from overlap) and take
    turns; a piece on another unit (a copy on the copy engine) runs beside them. So the pieces
    fall into classes joined by such pairs. A class of k takes turns at its worst pair's
    efficiency c (each switch costs the same however many take turns: three contexts deliver
    what two do), each of its pieces at c / k. The m classes overlap as single pieces do:
    together 1 + (m - 1) x mean(e - 1) over the pairs between classes (within [1, m]), each
    class an equal part of that. One piece per class (every pair above 1) is the rule for
    pieces that overlap: n deliver 1 + (n - 1) x mean(e - 1), each an equal share. A copy
    beside the classes' turn-taking never speeds them up: it adds its own unit's work."""
    n = len(tags)
    if n < 2:
        return (Fraction(1),) * n
    eff = {(i, j): Fraction(repr(pair_efficiency(profile, tags[i], tags[j]))).limit_denominator(1000)
           for i in range(n) for j in range(i + 1, n)}
    classes = _turn_taking_classes(n, [pair for pair, e in eff.items() if e <= 1])
    cross = [e - 1 for (i, j), e in eff.items() if classes[i] != classes[j]]
    m = len(set(classes))
    together = Fraction(1) if m == 1 else min(Fraction(m), max(
        Fraction(1), 1 + (m - 1) * sum(cross, Fraction(0)) / len(cross)))
    out = []
    for i in range(n):
        members = [k for k in range(n) if classes[k] == classes[i]]
        inner = [eff[(a, b)] for a in members for b in members if a < b]
        turns = min(Fraction(1), min(inner)) if inner else Fraction(1)
        out.append(together / m * turns / len(members))
    return tuple(out)


def _turn_taking_classes(n: int, pairs: list[tuple[int, int]]) -> list[int]:
    """For pieces 0..n-1, the class each is in: pieces joined (directly or through others) by a
    pair in `pairs` share a class, named by its lowest piece."""
    label = list(range(n))

    def root(k: int) -> int:
        while label[k] != k:
            k = label[k]
        return k

    for a, b in pairs:
        ra, rb = root(a), root(b)
        label[max(ra, rb)] = min(ra, rb)
    return [root(k) for k in range(n)]


def shared_gpu_groups(program: FrameProgram, profile: HardwareProfile) -> dict[int, tuple[WorkTag, ...]]:
    """Physical GPUs whose queues must share them: the work the program puts on each, where
    two pieces on different queues overlap less than perfectly (efficiency < 2). Never on
    CPU-emulated GPUs: the host's cores are their shared resource (SharedCores)."""
    if profile.host.gpus_share_cpu:
        return {}
    used: dict[int, set[WorkTag]] = {}
    for tasks in program.templates:
        for t in tasks:
            if not isinstance(t, (HostCopyTask, CpuTask)):  # the host's work, not a GPU's
                used.setdefault(profile.physical_of(t.queue.device), set()).add(work_tag(t))
    out: dict[int, tuple[WorkTag, ...]] = {}
    for phys, tags in used.items():
        ts = sorted(tags, key=str)
        if any(a[0] != b[0] and pair_efficiency(profile, a, b) < 2
               for i, a in enumerate(ts) for b in ts[i + 1:]):
            out[phys] = tuple(ts)
    return out


class Executor(Protocol):
    """What the engine asks of an executor (Dedicated, Interpreter, SharedCores and SharedGpu are
    the kinds)."""

    #: whether other devices draw on the same cores (its `channel` is then one of the run's)
    shared: bool
    #: whether a copy is work on the cores (a memcpy) rather than a crossing of a link channel
    copies_on_cores: bool
    #: whether host threads waking on inputs take turns (the default where the profile does
    #: not say, `host.serial_dispatch`)
    serial_dispatch: bool

    @property
    def channel(self) -> Channel | None:
        """The channel of the cores it shares (None where it shares none)."""

    def runner(self, ns: int, cores: Fraction | int = 1) -> tuple[Runner | None, int]: ...

    def task_runner(self, task: Task, ns: int) -> tuple[Runner | None, int]: ...

    def work(self, ns: int) -> simpy.Event: ...

    def background(self) -> Callable[[int], object] | None: ...

    def cores(self, task: Task) -> Fraction: ...


def measured_executors(env: Environment, costs: CostModel) -> dict[str, Executor]:
    """Every device and the host on one pool of the host's cores that measured work occupies
    (:class:`MeasuredCores`): the replay of a run on CPU-emulated GPUs."""
    pool = MeasuredCores(env, costs)
    out: dict[str, Executor] = {f"gpu{i}": pool for i in range(len(costs.profile.gpus))}
    out["host"] = pool
    return out


def make_executors(env: Environment, costs: CostModel, shared: bool,
                   program: FrameProgram | None = None) -> dict[str, Executor]:
    """One executor per device name ("gpu<i>") and "host". `shared`: every device and the host
    draw on the host's cores (the shared_executor effect). `program` (the shared_gpu effect):
    the logical GPUs of each physical GPU whose queues share it get one SharedGpu."""
    profile = costs.profile
    one: Executor = SharedCores(env, costs) if shared else Dedicated(env)
    out: dict[str, Executor] = {f"gpu{i}": one for i in range(len(profile.gpus))}
    out["host"] = Interpreter(env) if profile.host.shared_interpreter and not shared else one
    if program is not None and not shared:
        for phys in shared_gpu_groups(program, profile):
            gpu_ex = SharedGpu(env, profile, phys)
            for i in range(len(profile.gpus)):
                if profile.physical_of(i) == phys:
                    out[f"gpu{i}"] = gpu_ex
    return out
