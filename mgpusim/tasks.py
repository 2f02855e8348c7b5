"""The vocabulary of schedules: tasks bound to abstract resources, with dependencies.

A schedule is data. Both executors (the SimPy simulator and the Vulkan runner) read the same
task specs, so every task kind here is one that a real renderer can execute: a pass on a queue,
a copy on a queue over a path, a chunked host-to-host copy on the host thread pool.
Nothing here knows about time: costs come from :mod:`mgpusim.costs`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping

QueueFamily = Literal["graphics", "compute", "transfer"]
CopyPath = Literal["d2h", "h2d", "d2d", "p2p"]


@dataclass(frozen=True, slots=True)
class QueueRef:
    """One queue of one device: `gpu{device}.{family}` (index > 0 appends `#index`)."""

    device: int
    family: QueueFamily
    index: int = 0

    @property
    def engine(self) -> str:
        return self.family if self.index == 0 else f"{self.family}#{self.index}"

    @property
    def device_name(self) -> str:
        return f"gpu{self.device}"

    def __str__(self) -> str:
        return f"{self.device_name}.{self.engine}"


@dataclass(frozen=True, slots=True)
class Dep:
    """Task `task` of frame `frame + offset` must finish first (offset <= 0)."""

    task: str
    offset: int = 0


@dataclass(frozen=True, slots=True)
class PassTask:
    """A render or compute pass on a queue.

    `kind` selects the cost coefficients in the GPU profile (fragment_loop, mesh, composite,
    present, particle_update, ...); `work` gives the amounts the coefficients multiply
    (pixels, pixel_iterations, triangles, inputs, particles, ...).
    """

    name: str
    step: str
    queue: QueueRef
    kind: str
    work: Mapping[str, float] = field(default_factory=dict)
    deps: tuple[Dep, ...] = ()
    #: Skip this instance (record nothing, finish at once) when the previous frame's instance
    #: is still running at submit time: the particle demo's "new wait" policy.
    skip_if_busy: bool = False


@dataclass(frozen=True, slots=True)
class CopyTask:
    """A copy recorded on a queue that moves `bytes` over a path.

    `d2h`/`h2d` cross the device's PCIe link (one channel per direction); `p2p` crosses a
    peer link to device `peer`; `d2d` stays in device memory.
    """

    name: str
    step: str
    queue: QueueRef
    path: CopyPath
    bytes: int
    deps: tuple[Dep, ...] = ()
    peer: int | None = None
    skip_if_busy: bool = False


@dataclass(frozen=True, slots=True)
class HostCopyTask:
    """A host-to-host memcpy, split into chunks (>= chunk_min_bytes) over the memcpy threads."""

    name: str
    step: str
    bytes: int
    deps: tuple[Dep, ...] = ()
    chunk_min_bytes: int = 512 * 1024
    skip_if_busy: bool = False


Task = PassTask | CopyTask | HostCopyTask


def engine_of(task: Task) -> tuple[str, str]:
    """(device, engine) a task occupies; host copies are placed on threads when they run."""
    if isinstance(task, HostCopyTask):
        return "host", "memcpy"
    return task.queue.device_name, task.queue.engine
