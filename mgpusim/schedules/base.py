"""Schedules as data: a registry of builders that turn (config, scene, profile) into a
:class:`FrameProgram`, the per-frame task lists both executors run.

Adding a schedule is adding one module that calls :func:`register`. Everything else the tool
needs to know about the schedule travels in the program's typed fields, filled by the builder:
what each task reads and writes (`resources`, for the Vulkan runner), what every GPU holds
(`footprints`, for the memory check) and which skippable tasks have a rate of their own
(`rate_tasks`). No other module keeps per-schedule rules.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Mapping, Sequence

from mgpusim.model import limits as L
from mgpusim.model.errors import ScheduleError
from mgpusim.model.geometry import Placement
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import PassSpec
from mgpusim.model.tasks import CopyTask, CpuTask, Dep, HostCopyTask, PassTask, QueueRef, Resource, Task
from mgpusim.model.work_terms import pass_work


@dataclass(frozen=True)
class Footprint:
    """One GPU's resident data: `share` of the scene's data set plus fixed buffers (bytes):
    its render `targets` and the `staging` buffers that receive data from other GPUs."""

    gpu: int
    share: float
    targets: int
    staging: int
    #: With a sectioned data set: the whole sections this GPU holds and their bytes (which
    #: then replace `share` x the data set).
    sections: tuple[str, ...] = ()
    section_bytes: int | None = None

    def data(self, dataset_bytes: int) -> int:
        """Bytes of the data set this GPU holds."""
        if self.section_bytes is not None:
            return self.section_bytes
        return int(round(self.share * dataset_bytes))

    def used(self, dataset_bytes: int) -> int:
        return self.data(dataset_bytes) + self.targets + self.staging


@dataclass(frozen=True)
class FrameProgram:
    """The work of every frame. Frame f runs `templates[f % len(templates)]`, in that
    submission order; `present_task` names the task whose end is the frame's present.

    - `record`: facts about the program that results carry in their configuration (tile rows,
      buffers, bytes moved per frame, ...); written out, never read back by other modules.
    - `footprints`: every GPU's resident data (empty: each GPU holds one full set).
    - `resources`: the buffers and images the tasks' reads/writes/src/dst name, so that a real
      executor can allocate them; None when the schedule does not bind its tasks (the Vulkan
      runner refuses it).
    - `rate_tasks`: skippable tasks whose completion rate the summary reports.
    """

    schedule: str
    gpus: int
    frames: int
    warmup_frames: int
    templates: tuple[tuple[Task, ...], ...]
    present_task: str = "present"
    record: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    footprints: tuple[Footprint, ...] = ()
    resources: tuple[Resource, ...] | None = None
    rate_tasks: tuple[str, ...] = ()
    #: Display refresh rate (Hz) the present waits for (vsync, FIFO: one flip per refresh);
    #: 0 = present as soon as its work ends. Set from `schedule.refresh_hz` for every schedule.
    refresh_hz: float = 0.0

    def tasks(self, frame: int) -> tuple[Task, ...]:
        return self.templates[frame % len(self.templates)]

    @property
    def buffers(self) -> int:
        """The deepest multi-buffering of the declared resources (1 without resources)."""
        return max((r.buffers for r in self.resources or ()), default=1)


#: Bound on `schedule.refresh_hz` (vsync).
MAX_REFRESH_HZ = 10_000.0
#: The application's thread that records and submits frames (`schedule.cpu_frame_us` and the
#: schedules' CPU tasks run on it).
MAIN_THREAD = "main"


def with_cpu_frame(program: FrameProgram, cpu_frame_us: float, frames_in_flight: int) -> FrameProgram:
    """The program with the application's own CPU work per frame (`cpu.frame`, on the main
    thread, first in submission order): it starts once frame f-fif was presented, and every
    task of the frame with no input of its own frame waits for it (the thread submits them)."""
    if not cpu_frame_us:
        return program
    cpu = CpuTask("cpu.frame", "cpu", MAIN_THREAD, fixed_ns=cpu_frame_us * 1000,
                  deps=(Dep(program.present_task, -frames_in_flight),))
    gate = Dep(cpu.name)

    def gated(task: Task) -> Task:
        if any(d.offset == 0 for d in task.deps):
            return task
        return dataclasses.replace(task, deps=task.deps + (gate,))
    templates = tuple((cpu,) + tuple(gated(t) for t in tasks) for tasks in program.templates)
    return dataclasses.replace(program, templates=templates)


def chain_passes(specs: Sequence[PassSpec], queue: QueueRef, first_deps: tuple[Dep, ...],
                 pixels: float, name: Callable[[PassSpec], str], share: float = 1.0,
                 step: Callable[[PassSpec], str] = lambda spec: "render",
                 place: Placement | None = None) -> list[PassTask]:
    """Passes in order on one queue: the first waits for `first_deps`, each later one for the
    pass before it (a queue's submission order with a semaphore per hand-off). `place`: where
    they draw (the part of the frame, geometry share and camera), for the work terms that
    depend on it (a mesh's visible triangles)."""
    out: list[PassTask] = []
    for spec in specs:
        deps = (Dep(out[-1].name),) if out else first_deps
        out.append(PassTask(name(spec), step(spec), queue, spec.kind,
                            MappingProxyType(pass_work(spec, pixels, share, place)), deps))
    return out


def task_device(task: Task) -> str:
    """Where a task runs: `gpu{i}` for queue work, `host` for host copies and CPU tasks."""
    return "host" if isinstance(task, (HostCopyTask, CpuTask)) else task.queue.device_name


def wakes_host(producer: Task, task: Task, leads: bool = False) -> bool:
    """Whether a host thread must wake to act on `task`'s input from `producer`: always for a
    host copy (the dispatching thread) and for the leader of a skippable chain (`leads`: it
    decides on the host, once its inputs have ended, whether its chain is still busy), for a
    CPU task unless the input ran on its own thread, else when the input ran on another device."""
    if isinstance(task, HostCopyTask) or leads:
        return True
    if isinstance(task, CpuTask):
        return not (isinstance(producer, CpuTask) and producer.thread == task.thread)
    return task_device(producer) != task_device(task)


def leads_chain(task: Task, frame_tasks: Mapping[str, Task]) -> bool:
    """A skippable task that decides for its chain: it has no skippable input of its own frame
    (`frame_tasks`: its frame's tasks by name). A follower is skipped exactly when such an
    input was (:mod:`mgpusim.schedules.skipping`), so only a leader looks at the chain's state."""
    return task.skip_if_busy and not any(d.offset == 0 and frame_tasks[d.task].skip_if_busy
                                         for d in task.deps)


def present_work(pixels: float) -> Mapping[str, float]:
    """The work terms of presenting a frame of `pixels` (a full-frame copy)."""
    return MappingProxyType(pass_work(PassSpec("present", "present"), pixels))


def present_task(queue: QueueRef, pixels: float, after: str) -> PassTask:
    """The frame's `present` task (FrameProgram's default end of a frame), after task `after`."""
    return PassTask("present", "present", queue, "present", present_work(pixels), (Dep(after),))


def queue_or_graphics(profile: HardwareProfile, device: int, family: str) -> QueueRef:
    """The device's first queue of `family`, or its graphics queue when it has none."""
    if profile.gpus[device].has_queue(family):
        return QueueRef(device, family)  # type: ignore[arg-type]
    return QueueRef(device, "graphics")


def check_program(program: FrameProgram, profile: HardwareProfile) -> None:
    """Build-time checks: every queue exists, dependencies name real tasks, names are unique."""
    names = [{t.name for t in tasks} for tasks in program.templates]
    for phase, tasks in enumerate(program.templates):
        if len(names[phase]) != len(tasks):
            raise ScheduleError(f"{program.schedule}: duplicate task names in frame phase {phase}")
        if program.present_task not in names[phase]:
            raise ScheduleError(f"{program.schedule}: phase {phase} has no {program.present_task!r} task")
        for task in tasks:
            _check_task(program, profile, phase, task, names)


def _check_task(program: FrameProgram, profile: HardwareProfile, phase: int, task: Task,
                names: list[set[str]]) -> None:
    period = len(program.templates)
    if isinstance(task, (PassTask, CopyTask)):
        q = task.queue
        if not 0 <= q.device < len(profile.gpus) or not profile.gpus[q.device].has_queue(q.family, q.index):
            raise ScheduleError(f"task {task.name!r} uses {q}, which profile {profile.name!r} lacks")
    for dep in task.deps:
        if dep.offset > 0:
            raise ScheduleError(f"task {task.name!r} depends on a later frame ({dep})")
        if dep.task not in names[(phase + dep.offset) % period]:
            raise ScheduleError(f"task {task.name!r} depends on {dep.task!r} (frame offset "
                                f"{dep.offset}), which that frame does not have")
    if isinstance(task, CpuTask) and not task.cost_ns <= L.MAX_TASK_NS:
        raise ScheduleError(f"CPU task {task.name!r} would take {task.cost_ns:.3g} ns, more than "
                            f"the {L.MAX_TASK_NS:.0e} ns one task may last")
    if isinstance(task, HostCopyTask) and task.chunk_min_bytes < 1:
        raise ScheduleError(f"task {task.name!r}: chunk_min_bytes must be >= 1")

