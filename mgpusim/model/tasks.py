"""The vocabulary of schedules: tasks bound to abstract resources, with dependencies.

A schedule is data. Both executors (the SimPy simulator and the Vulkan runner) read the same
task specs, so every task kind here is one that a real renderer can execute: a pass on a queue,
a copy on a queue over a path, a chunked host-to-host copy on the host thread pool.
Nothing here knows about time: costs come from :mod:`mgpusim.model.costs`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal, Mapping

QueueFamily = Literal["graphics", "compute", "transfer"]
CopyPath = Literal["d2h", "h2d", "d2d", "p2p", "group"]


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

    @classmethod
    def of(cls, device_name: str, engine: str) -> "QueueRef | None":
        """The queue a trace row names (`gpu1`, `transfer#1`); None for the host's rows or a
        name that is no queue."""
        family, _, index = engine.partition("#")
        if (not device_name.startswith("gpu") or not device_name[3:].isdigit()
                or family not in ("graphics", "compute", "transfer") or (index and not index.isdigit())):
            return None
        return cls(int(device_name[3:]), family, int(index or 0))  # type: ignore[arg-type]


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
    #: Logical resources (names of :class:`Resource`) the pass samples and renders into, and
    #: the knobs a real renderer needs (tile rectangle, iterations, geometry share, ...). Only
    #: the Vulkan runner reads these; the simulator costs the pass from `kind` and `work`.
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, slots=True)
class CopyTask:
    """A copy recorded on a queue that moves `bytes` over a path.

    `d2h`/`h2d` cross the device's PCIe link (one channel per direction); `p2p` crosses a
    peer link to device `peer`; `group` goes GPU to GPU over PCIe inside a device group
    (linked-node adapter): no host memory, at the slower of the source's d2h and the
    destination's h2d rate; `d2d` stays in device memory. A `p2p` or `group` copy with `pull`
    is recorded on the destination and reads the peer's memory (else pushed from the source).
    """

    name: str
    step: str
    queue: QueueRef
    path: CopyPath
    bytes: int
    deps: tuple[Dep, ...] = ()
    peer: int | None = None
    skip_if_busy: bool = False
    pull: bool = False
    #: Logical resources copied from and to (the Vulkan runner's binding; the simulator ignores it).
    src: str | None = None
    dst: str | None = None
    #: Where in them (the runner's binding): `rows` = (first row, rows) of a chunk of an image,
    #: `dst_offset` = (x, y) of the destination image the copy writes at, `extent`, `images`
    #: (several images through one buffer), `unsupported` (why the runner refuses the copy).
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def ends(self) -> tuple[int, int]:
        """(source, destination) device of a `p2p` or `group` copy: pulled by the destination
        (`pull`), else pushed by the source."""
        other = self.peer if self.peer is not None else self.queue.device
        return (other, self.queue.device) if self.pull else (self.queue.device, other)


@dataclass(frozen=True, slots=True)
class HostCopyTask:
    """A host-to-host memcpy, split into chunks (>= chunk_min_bytes) over the memcpy threads
    (the host's pool, or threads of the copy's own: `own_threads`)."""

    name: str
    step: str
    bytes: int
    deps: tuple[Dep, ...] = ()
    chunk_min_bytes: int = 512 * 1024
    skip_if_busy: bool = False
    #: The source is host-visible memory the CPU does not cache (a write-combined staging
    #: buffer): its parts read at `host.uncached_read_gbps` (the uncached_reads effect).
    uncached: bool = False
    #: The copy starts threads of its own, one per part (the thesis's `parallelCopy`: a new
    #: std::thread per chunk, every call), instead of queueing its parts for the host's pool of
    #: memcpy threads: two such copies at once run side by side, sharing host memory (and, on
    #: CPU-emulated GPUs, the cores), not one after the other.
    own_threads: bool = False

    #: Host-visible buffers copied from and to (the Vulkan runner's binding).
    src: str | None = None
    dst: str | None = None

    def parts(self, threads: int) -> int:
        """How many parts the copy is split into: one per thread, each >= chunk_min_bytes
        (the reference renderer's rule; the simulator and the runner both use it)."""
        return max(1, min(threads, self.bytes // self.chunk_min_bytes))

    def part_start_ns(self, part: int, parts: int, thread_start_ns: int) -> int:
        """When part `part` of `parts` starts, after the copy is dispatched: on threads of its
        own the caller starts them one after another (bp's parallelCopy), `thread_start_ns`
        each; a single part is its memmove on the calling thread, and the pool's threads are
        running already: no start."""
        if not self.own_threads or parts < 2:
            return 0
        return (part + 1) * thread_start_ns


@dataclass(frozen=True, slots=True)
class CpuTask:
    """Per-frame work of the application on one of its host threads (`thread`, e.g. "main":
    game logic, command recording, a CPU-side copy, the wait on a fence that precedes it).

    Its cost is its own linear model, `fixed_ns + ns_per_item * items` (integer ns, rounded
    half up once): the schedule that places it says what an item is (a particle, a byte).
    Where the engine's host work is modelled (the host_frame_work effect) it also costs
    `host.thread_start_ns` for each of the `threads` it starts (and joins) and `host.record_ns`
    for each of the `command_buffers` it records and submits.
    Tasks of one thread run in submission order, one at a time; a CPU task fed by a GPU or
    the memcpy threads starts `host.dispatch_ns` after that input (the thread wakes on a fence).
    Only the simulator runs it: the Vulkan runner refuses a program that has one."""

    name: str
    step: str
    thread: str = "main"
    fixed_ns: float = 0.0
    ns_per_item: float = 0.0
    items: float = 0.0
    deps: tuple[Dep, ...] = ()
    skip_if_busy: bool = False
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType(
        {"unsupported": "CPU tasks are simulated only: the Vulkan runner runs GPU work and copies"}))
    threads: int = 0
    command_buffers: int = 0
    #: the thread sleeps for its time (a timer, such as a window toolkit's update gap): it
    #: takes no core, so on CPU-emulated GPUs it slows no pass beside it
    idle: bool = False

    @property
    def cost_ns(self) -> float:
        return self.fixed_ns + self.ns_per_item * self.items


Task = PassTask | CopyTask | HostCopyTask | CpuTask


@dataclass(frozen=True, slots=True)
class Resource:
    """A buffer or image that tasks name in reads/writes/src/dst, declared by the schedule in
    `FrameProgram.resources` so that a real executor can allocate it.

    `device` None is host memory imported by every device in `shared_by`
    (VK_EXT_external_memory_host). An image is RGBA8 colour, plus a D16 depth image when `depth`;
    in a buffer the colour bytes come first, then the depth bytes. A resource with `buffers` > 1
    is multi-buffered: frame f uses copy `f % buffers`.
    """

    name: str
    device: int | None
    kind: Literal["image", "buffer"]
    width: int = 0
    height: int = 0
    depth: bool = False
    bytes: int = 0
    buffers: int = 1
    host_visible: bool = False
    shared_by: tuple[int, ...] = ()

