"""The concrete task graph of a run: one node per (frame, task), streams, and how each
dependency is honoured.

Why three kinds of edge: Vulkan gives different tools for each.
- `order`: producer and consumer on the same VkQueue, producer submitted first. Submission order
  plus the full barriers `Gpu.submit` puts around every task is enough.
- `semaphore`: same device, different queues (render -> copy engine -> composite). A binary
  semaphore the producer signals and the consumer waits; the consumer is only submitted after
  the producer (the binary-semaphore rule).
- `host`: different devices (each simulated GPU is its own VkInstance on lavapipe, so nothing is
  shared between them) or a host copy on either side: the host waits for the producer's fence
  (or the host copy's end) before it submits or copies.
Every stream handles its nodes in (frame, template position) order; the plan checks that each
dependency points to an earlier position, so that order can never deadlock.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from mgpusim.model.errors import ScheduleError
from mgpusim.model.tasks import Task
from mgpusim.real.runner.latch import Latch
from mgpusim.real.runner.work import CpuWork, GpuWork, HostWork, Work
from mgpusim.schedules.base import FrameProgram, leads_chain
from mgpusim.schedules.task_inputs import waits_for_labels

EdgeKind = Literal["order", "semaphore", "host"]
HOST_STREAM = "host"


@dataclass(eq=False)
class Node:
    """One task of one frame, with the events the executor threads meet on."""

    frame: int
    index: int
    task: Task
    work: Work
    stream: str
    waits_for: str
    deps: list[tuple["Node", EdgeKind]] = field(default_factory=list)
    #: consumers that wait on a semaphore this node signals
    sem_consumers: list["Node"] = field(default_factory=list)
    signals: dict[int, Any] = field(default_factory=dict)  # id(consumer) -> Semaphore
    waits: list[Any] = field(default_factory=list)  # Semaphores this node waited on
    submitted: Latch = field(default_factory=Latch)
    completed: Latch = field(default_factory=Latch)
    submission: Any = None
    parts_left: int = 0
    skipped: bool = False  # a skip_if_busy task that was skipped (see Executor)

    @property
    def label(self) -> str:
        return f"frame {self.frame} {self.task.name}"


#: Streams of CPU tasks: `cpu/<thread>`, one application thread each.
CPU_STREAM = "cpu/"


def stream_of(work: Work) -> str:
    if isinstance(work, HostWork):
        return HOST_STREAM
    if isinstance(work, CpuWork):
        return CPU_STREAM + work.thread
    return f"gpu{work.device}/{work.queue.family.index}"


def build_nodes(program: FrameProgram, works: list[dict[str, Work]], frames: int) -> list[Node]:
    """Nodes of frames 0..frames-1 in (frame, position) order, with their classified edges."""
    period = len(program.templates)
    labels = waits_for_labels(program)
    index = [{t.name: t for t in tasks} for tasks in program.templates]
    leads = [{t.name: leads_chain(t, index[q]) for t in tasks} for q, tasks in enumerate(program.templates)]
    nodes: list[Node] = []
    by_key: dict[tuple[int, str], Node] = {}
    for f in range(frames):
        phase = f % period
        for i, task in enumerate(program.templates[phase]):
            work = works[phase][task.name]
            node = Node(f, i, task, work, stream_of(work), labels[phase][task.name])
            nodes.append(node)
            by_key[(f, task.name)] = node
    for node in nodes:
        for dep in node.task.deps:
            pf = node.frame + dep.offset
            if pf < 0:
                continue
            prod = by_key[(pf, dep.task)]
            if (prod.frame, prod.index) >= (node.frame, node.index):
                raise ScheduleError(f"{node.label} depends on {prod.label}, which comes later in "
                                    f"the frame's submission order: the runner submits in order")
            kind = _edge(prod.work, node.work, prod.stream == node.stream,
                         leads[node.frame % period][node.task.name])
            node.deps.append((prod, kind))
            if kind == "semaphore":
                prod.sem_consumers.append(node)
        node.deps.sort(key=earliest_first)
    return nodes


def earliest_first(dep: tuple[Node, EdgeKind]) -> tuple[int, int]:
    """The order a submit thread checks a node's inputs in: the earliest submitted first.

    Why: each input from another queue costs the thread a fence call, and after the call a
    turn at the interpreter among the run's busy Python threads. Checked in the task's listed
    order, XR strong scaling's render waited on the last frame's render first and only then
    looked at the present and acquire of two frames back, long finished: two more turns after
    the wake, each up to the switch interval, before the submit. The older inputs are checked
    while the newest is still running, so only its wake stands between its end and the submit."""
    producer = dep[0]
    return producer.frame, producer.index


def _edge(prod: Work, cons: Work, same_stream: bool, leads: bool = False) -> EdgeKind:
    """How the consumer waits for the producer: queue order on one stream, a semaphore between
    queues of one device, else on the host. A chain's leader always waits on the host: it
    decides at its submit time whether the work before it is still running, as the model does
    when its inputs have ended; ordered behind them on the device instead, its submit thread
    ran frames ahead and found the previous instance still queued (1-GPU particle runs skipped
    97-99 % of their updates where the model skips none or every other one)."""
    if leads:
        return "host"
    if same_stream:
        return "order" if isinstance(prod, GpuWork) else "host"
    if isinstance(prod, GpuWork) and isinstance(cons, GpuWork) and prod.device == cons.device:
        return "semaphore"
    return "host"
