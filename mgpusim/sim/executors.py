"""Executors: what runs a device's work. The engine is given one per device and the host.

A real GPU runs its own work: a pass of `ns` is a delay of `ns` (:class:`Dedicated`). GPUs
emulated on the host CPU (lavapipe) share its cores with each other, the memcpy threads and the
submit threads (:class:`SharedCores`): a pass of `ns` that keeps `cores` busy is `ns x cores`
core-ns of work on one fluid channel of the host's cores, so passes that overlap slow each other.
The engine never asks which kind it has: it asks the executor for a *runner* once per task when
it builds, and yields what the runner returns in its hot loop. The same mechanism can carry any
pool that several devices or queues draw on (e.g. the queues of one GPU sharing its cores).
"""
from __future__ import annotations

from fractions import Fraction
from typing import Callable, Protocol

import simpy

from ..costs import CostModel
from ..tasks import CopyTask, HostCopyTask, PassTask, Task
from .channel import Channel

#: A runner: called with an amount, returns the event that fires when that work is done.
Runner = Callable[[int], simpy.Event]


class Dedicated:
    """A device with its own cores: work of `ns` takes `ns`, whatever else runs."""

    shared = False
    #: a copy crosses a link channel (a real copy engine), not the device's own cores
    copies_on_cores = False

    def __init__(self, env: simpy.Environment):
        self.env = env

    def runner(self, ns: int, cores: Fraction | int = 1) -> tuple[Runner | None, int]:
        """(runner, amount) for work of `ns`; no runner for no work (nothing to wait for)."""
        return (self.env.timeout, ns) if ns else (None, 0)

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

    def __init__(self, env: simpy.Environment, costs: CostModel):
        host = costs.profile.host
        self.costs = costs
        cores = Fraction(host.cpu_cores)
        eff = Fraction(repr(host.oversubscribed_efficiency))
        self.channel = Channel(env, "host.cpu", cores, cores * eff if eff != 1 else None)

    def runner(self, ns: int, cores: Fraction | int = 1) -> tuple[Runner | None, int]:
        cores = Fraction(cores)
        transfer = self.channel.transfer

        def run(amount: int) -> simpy.Event:
            return transfer(amount, cores)
        return run, -(-ns * cores.numerator // cores.denominator)

    def work(self, ns: int) -> simpy.Event:
        """One thread's `ns` of time: one core's work on the pool."""
        return self.channel.transfer(ns, 1)

    def background(self) -> Callable[[int], object] | None:
        """One core's work for `ns` that nobody waits on (a submit thread recording commands)."""
        return lambda ns: self.channel.transfer(ns, 1)

    def cores(self, task: Task) -> Fraction:
        """Cores a task keeps busy: a copy the queue thread, a pass its kind's measured
        `cores`, else the GPU's rasterizer threads."""
        host = self.costs.profile.host
        if isinstance(task, (CopyTask, HostCopyTask)):
            return Fraction(1)
        gpu = self.costs.profile.gpus[task.queue.device]
        threads = Fraction(min(gpu.cpu_threads or host.cpu_cores, host.cpu_cores))
        cost = gpu.costs.get(task.kind) if isinstance(task, PassTask) else None
        if cost is None or cost.cores is None:
            return threads
        return min(Fraction(repr(cost.cores)).limit_denominator(1000), threads)


class Executor(Protocol):
    """What the engine asks of an executor (Dedicated and SharedCores are the two kinds)."""

    #: whether other devices draw on the same cores (its `channel` is then one of the run's)
    shared: bool
    #: whether a copy is work on the cores (a memcpy) rather than a crossing of a link channel
    copies_on_cores: bool

    def runner(self, ns: int, cores: Fraction | int = 1) -> tuple[Runner | None, int]: ...

    def work(self, ns: int) -> simpy.Event: ...

    def background(self) -> Callable[[int], object] | None: ...

    def cores(self, task: Task) -> Fraction: ...


def make_executors(env: simpy.Environment, costs: CostModel, shared: bool) -> dict[str, Executor]:
    """One executor per device name ("gpu<i>") and "host". `shared`: every device and the host
    draw on the host's cores (the shared_executor effect)."""
    one: Executor = SharedCores(env, costs) if shared else Dedicated(env)
    names = [f"gpu{i}" for i in range(len(costs.profile.gpus))] + ["host"]
    return {name: one for name in names}
