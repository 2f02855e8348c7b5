"""The five-step pipeline's frame loop as the thesis's reference code runs it on the host.

The reference renderer (docs/sources.md, "The five-step pipeline": the `bpMulti` compositor of
the thesis's library and the `bpQt` window loop) does per frame, on the application's threads:

1. the main thread starts one thread per GPU that renders and one per secondary that copies
   (one more for a secondary's depth; `std::async`: started and joined every frame);
2. each GPU's thread records its render, submits it and waits for its queue to be idle
   (`vkQueueWaitIdle`); a secondary's thread then records the download of its contribution
   to a staging buffer on its transfer queue, submits it and waits idle again;
3. meanwhile the main thread copies the previous frame's contributions from the secondaries'
   staging buffers to the primary's on every hardware thread (`Compositor::hostCopyStep`: every
   secondary's copy at once, each a `parallelCopy` of its own, split into one part per hardware
   thread, each part a new thread; the source is a `CPU_ONLY` buffer, host-coherent and not
   cached): the copies run side by side (`HostCopyTask.own_threads`), sharing host memory
   and the cores, not one after another on a pool; then it records the upload, submits it and
   waits idle;
4. it joins the primary's thread, records the composite of every contribution (the primary's
   own included), joins the secondaries' threads, submits the composite, waits idle and
   presents; only then does the next frame start.

Two details of the order decide a frame on a GPU without a transfer queue of its own (lavapipe):
the main thread joins the primary's render thread *before* it records the upload there (the
upload then queues behind the primary's render of the next frame; with a dedicated transfer
queue it records the upload first), and after the present the window asks for the next frame
through Qt's update request, a timer of `QT_QPA_UPDATE_IDLE_TIME` ms (5 by default) during
which nothing runs: `update_gap_ns` (bp's `bpQt/src/Window.cpp`, `frame()`; vmgpu runs
continuously, every frame requesting the next).

So every frame ends in a barrier: no GPU starts frame f+1 before frame f was presented, and
every hand-off between a thread and a queue costs a wake-up (`host.dispatch_ns`). The thread
starts and the recordings are CPU tasks that cost `host.thread_start_ns` and `host.record_ns`
(the host_frame_work effect); the host copy reads uncached memory (the uncached_reads effect).
As in the reference code, the copies and the composite of a frame's loop move the
contributions rendered in the loop before (the latency of the data is one loop longer than the
trace's frame latency says).
"""
from __future__ import annotations

import dataclasses
from types import MappingProxyType
from typing import Mapping, Sequence, TypeVar

from mgpusim.model.tasks import CopyTask, CpuTask, Dep, HostCopyTask, PassTask, Task
from mgpusim.schedules.base import MAIN_THREAD

T = TypeVar("T", PassTask, CopyTask, HostCopyTask, CpuTask)

#: `parallelCopy`'s smallest part (bp/src/Util.cpp of the thesis's library, `CHUNK_SIZE`):
#: 512 KiB since bp's commit "Larger chunk size for parallel copy" (2018-01-29; 1024 bytes
#: before it), the value vmgpu's pinned bp has. A copy up to it is one memmove on the calling
#: thread; a larger one is split into parts of max(bytes / hardware threads, 512 KiB).
PARALLEL_COPY_MIN_BYTES = 512 * 1024
#: The CPU task that stands for the window toolkit's gap between a present and the next frame.
UPDATE_GAP = "cpu.update_gap"
#: The steps of the host loop's CPU tasks (the trace's `step` column).
STEP = "host_loop"
#: The Vulkan runner runs these CPU tasks (it starts and joins their threads on an application
#: thread of their own and waits for their inputs' fences): mgpusim/real/runner/work.py.
RUNNABLE = MappingProxyType({"runner": STEP})


def gpu_thread(gpu: int) -> str:
    """The application thread that records and submits GPU `gpu`'s work."""
    return f"gpu{gpu}"


def as_built(tasks: Sequence[Task], gpus: int, renders: Sequence[str], depth: bool = False,
             update_gap_ns: int = 0) -> list[Task]:
    """The five-step `tasks` (renders, d2h{i}, host_copy{i}, h2d{i}, composite, present;
    `renders[i]`: GPU i's last render) run by the reference code's frame loop (module doc);
    `depth`: the contributions carry depth, whose host copy has a thread of its own;
    `update_gap_ns`: the window's idle time between a present and the next frame (module doc)."""
    by_name = {t.name: t for t in tasks}
    gap = _update_gap(update_gap_ns)
    start = Dep(gap[0].name if gap else "present", -1)
    if gpus == 1:  # one GPU renders straight to the window: record, submit, wait idle, present
        record = CpuTask("cpu.record0", STEP, MAIN_THREAD, command_buffers=1,
                         deps=(start,), params=RUNNABLE)
        return [record] + [_after(t, "cpu.record0") if _first_render(t, 0) else t for t in tasks] + gap
    secondaries = range(1, gpus)
    threads = 2 * gpus - 1 + (gpus - 1 if depth else 0)  # renders, copies, depth copies
    launch = CpuTask("cpu.launch", STEP, MAIN_THREAD, threads=threads, deps=(start,),
                     params=RUNNABLE)
    out: list[Task] = [launch]
    for i in range(gpus):
        out.append(CpuTask(f"cpu.record{i}", STEP, gpu_thread(i), command_buffers=1,
                           deps=(Dep(launch.name),), params=RUNNABLE))
    for t in tasks:
        if isinstance(t, PassTask) and t.step == "render":
            gpu = t.queue.device
            out.append(_after(t, f"cpu.record{gpu}") if _first_render(t, gpu) else t)
    for i in secondaries:
        out.append(CpuTask(f"cpu.record_d2h{i}", STEP, gpu_thread(i), command_buffers=1,
                           deps=(Dep(renders[i]),), params=RUNNABLE))
        d2h = by_name[f"d2h{i}"]
        out.append(dataclasses.replace(d2h, deps=(Dep(f"cpu.record_d2h{i}"),) + d2h.deps[1:]))
    staged = []
    for i in secondaries:  # the previous loop's contributions, copied on every hardware thread
        if f"host_copy{i}" in by_name:
            hc = _of_kind(by_name, f"host_copy{i}", HostCopyTask)
            out.append(dataclasses.replace(hc, deps=(Dep(f"d2h{i}", -1), Dep(launch.name)) + hc.deps[1:],
                                           chunk_min_bytes=PARALLEL_COPY_MIN_BYTES, uncached=True,
                                           own_threads=True))
            staged.append(Dep(hc.name))
        else:
            staged += [Dep(f"d2h{i}", -1), Dep(launch.name)]
    primary = _of_kind(by_name, renders[0], PassTask)
    shared_queue = any(_of_kind(by_name, f"h2d{i}", CopyTask).queue == primary.queue for i in secondaries)
    if shared_queue:  # no transfer queue of its own: the upload waits for the primary's render
        staged.append(Dep(renders[0]))
    out.append(CpuTask("cpu.record_upload", STEP, MAIN_THREAD, command_buffers=1, deps=tuple(staged),
                       params=RUNNABLE))
    for i in secondaries:
        h2d = by_name[f"h2d{i}"]
        out.append(dataclasses.replace(h2d, deps=(Dep("cpu.record_upload"),) + h2d.deps[1:]))
    joins = [Dep(f"h2d{i}") for i in secondaries] + [Dep(renders[0])] + [Dep(f"d2h{i}") for i in secondaries]
    out.append(CpuTask("cpu.record_composite", STEP, MAIN_THREAD, command_buffers=1, deps=tuple(joins),
                       params=RUNNABLE))
    out.append(dataclasses.replace(by_name["composite"], deps=(Dep("cpu.record_composite"),)))
    out.append(by_name["present"])
    return out + gap


def _update_gap(ns: int) -> list[Task]:
    """The window's wait after a present (none for 0): the main thread sleeps, no core taken."""
    if not ns:
        return []
    return [CpuTask(UPDATE_GAP, STEP, MAIN_THREAD, fixed_ns=float(ns), deps=(Dep("present"),),
                    idle=True, params=RUNNABLE)]


def _of_kind(by_name: Mapping[str, Task], name: str, kind: type[T]) -> T:
    """Task `name` of the five steps, which is a `kind` (a render a PassTask, h2d a CopyTask)."""
    task = by_name[name]
    assert isinstance(task, kind), f"{name} is a {type(task).__name__}"
    return task


def _first_render(task: Task, gpu: int) -> bool:
    """GPU `gpu`'s first render of the frame (the one its thread submits first)."""
    return (isinstance(task, PassTask) and task.step == "render" and task.queue.device == gpu
            and not any(d.offset == 0 and d.task.startswith("render") for d in task.deps))


def _after(task: Task, cpu: str) -> Task:
    """`task` submitted by the CPU task `cpu` (its frame-in-flight gates are implied by the
    loop's barrier)."""
    assert isinstance(task, (PassTask, CopyTask, HostCopyTask))
    return dataclasses.replace(task, deps=(Dep(cpu),) + tuple(task.deps))
