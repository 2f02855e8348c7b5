"""What each task of a FrameProgram does on Vulkan: a recorder for a queue, or host copy parts.

Why one small object per template task: passes and pipelines are built once (slow: shader JIT,
vertex upload) and then recorded every frame into the frame's buffered copy of its resources.
The mapping, kind by kind:
- render (fragment_loop / mesh) -> FragmentLoopTile / MeshShare into the task's `writes[0]`;
- composite_sort_first / _last -> CompositeInto the frame (load), sampling `reads`;
- present -> an image copy of the frame into the displayed image;
- d2h / h2d copies -> image <-> host-visible buffer (colour first, then depth);
- host copies -> numpy copies of byte ranges, one part per memcpy thread (>= chunk_min_bytes).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..errors import ScheduleError
from ..tasks import CopyTask, HostCopyTask, PassTask, Task
from ..vulkan.copies import copy_buffer_to_image, copy_image_to_buffer
from ..vulkan.device import Gpu, Queue
from ..vulkan.framepasses import (CompositeInto, FragmentLoopTile, MeshShare, copy_image,
                                  target_over)
from .resources import Resources


@dataclass
class GpuWork:
    """A queue task: `record(cmd, frame)` on `queue` of `gpu`; `engine` is the trace's name."""

    task: Task
    device: int
    gpu: Gpu
    queue: Queue
    engine: str
    record: Callable[[Any, int], None]
    nbytes: int
    fallback: bool  # the program asked for a queue family this device lacks
    cycle: int  # record(cmd, f) depends on f only through f % cycle

    def key(self, frame: int) -> tuple[int, int]:
        """Submissions with one key record the same commands: the Gpu records each command
        buffer once and submits it again (no Python recording in the steady state)."""
        return id(self), frame % self.cycle


@dataclass
class HostWork:
    """A host copy: `parts(frame)` gives (dst, src) byte views, one per memcpy thread."""

    task: HostCopyTask
    resources: Resources
    threads: int

    def parts(self, frame: int) -> list[tuple[np.ndarray, np.ndarray]]:
        t = self.task
        assert t.src is not None and t.dst is not None
        src = self.resources.host_array(t.src, self.resources.slot(t.src, frame))
        dst = self.resources.host_array(t.dst, self.resources.slot(t.dst, frame))
        if src.size < t.bytes or dst.size < t.bytes:
            raise ScheduleError(f"host copy {t.name!r} of {t.bytes} bytes between buffers of "
                                f"{src.size} and {dst.size} bytes")
        # the simulator's split (HostCopyTask.parts): equal parts, the last takes the remainder
        n = t.parts(self.threads)
        base = t.bytes // n
        bounds = [i * base for i in range(n)] + [t.bytes]
        return [(dst[a:b], src[a:b]) for a, b in zip(bounds, bounds[1:])]


Work = GpuWork | HostWork


def build_work(task: Task, gpus: list[Gpu], res: Resources, host_threads: int,
               owned: list[Any]) -> Work:
    """The executor of one template task; passes it builds are appended to `owned`."""
    if getattr(task, "skip_if_busy", False):
        raise ScheduleError(f"task {task.name!r}: skip_if_busy is not supported by the runner")
    if isinstance(task, HostCopyTask):
        if task.src is None or task.dst is None:
            raise ScheduleError(f"host copy {task.name!r} names no src/dst buffers")
        return HostWork(task, res, host_threads)
    q = task.queue
    if not 0 <= q.device < len(gpus):
        raise ScheduleError(f"task {task.name!r} runs on gpu{q.device}; the run has {len(gpus)}")
    if q.index != 0:
        raise ScheduleError(f"task {task.name!r} uses {q}; the runner opens one queue per family")
    gpu = gpus[q.device]
    dedicated = q.family == "graphics" or gpu.has_dedicated(q.family)
    engine = q.engine if dedicated else "graphics"
    if isinstance(task, PassTask):
        record, nbytes = _pass(task, gpu, res, owned), 0
    else:
        record, nbytes = _copy(task, res), task.bytes
    return GpuWork(task, q.device, gpu, gpu.queue(q.family), engine, record, nbytes, not dedicated,
                   res.cycle)


def _pass(task: PassTask, gpu: Gpu, res: Resources, owned: list[Any]) -> Callable[[Any, int], None]:
    p = dict(task.params)
    if task.step == "present" or task.kind == "present":
        (src,), (dst,) = task.reads, task.writes
        s, d = res.images(src)[0][0], res.images(dst)[0][0]
        return lambda cmd, frame: copy_image(cmd, s, d)
    if not task.writes:
        raise ScheduleError(f"pass {task.name!r} ({task.kind}) names no target (writes)")
    out = task.writes[0]
    frame_size = tuple(p.get("frame", ()))
    if task.kind in ("composite_sort_first", "composite_sort_last"):
        colour, depth = res.images(out)[0]
        target = target_over(gpu, colour, depth, clear=False)
        slots = max(res.resource(r).buffers for r in task.reads) if task.reads else 1
        inputs = [[res.images(r)[s % res.resource(r).buffers] for r in task.reads]
                  for s in range(slots)]
        try:
            work: Any = CompositeInto(gpu, target, frame_size, inputs, p["inputs"], bool(p["depth"]))
        except BaseException:
            target.destroy()
            raise
        owned.append(work)
        return lambda cmd, frame: work.record(cmd, frame % slots)
    targets = [target_over(gpu, c, d, clear=bool(p.get("clear", True)))
               for c, d in res.images(out)]
    try:
        if task.kind == "fragment_loop":
            work = FragmentLoopTile(gpu, targets, frame_size, p["rect"], p["origin"],
                                    int(p.get("iterations", 0)))
        elif task.kind == "mesh":
            work = MeshShare(gpu, targets, frame_size, int(p["triangles"]), int(p["first"]),
                             int(p["count"]))
        else:
            raise ScheduleError(f"pass {task.name!r}: kind {task.kind!r} has no Vulkan "
                                f"implementation in the runner (fragment_loop, mesh, composite_*, present)")
    except BaseException:  # the targets are not owned by anything yet
        for t in targets:
            t.destroy()
        raise
    owned.append(work)
    return lambda cmd, frame: work.record(cmd, res.slot(out, frame))


def _copy(task: CopyTask, res: Resources) -> Callable[[Any, int], None]:
    if task.src is None or task.dst is None:
        raise ScheduleError(f"copy {task.name!r} names no src/dst resources")
    dev = task.queue.device
    if task.path == "d2h":
        image_name, buffer_name = task.src, task.dst
    elif task.path == "h2d":
        image_name, buffer_name = task.dst, task.src
    else:
        raise ScheduleError(f"copy {task.name!r}: path {task.path!r} is not supported by the runner")
    images = res.images(image_name)
    if task.bytes == 0:  # an empty tile: nothing to move
        return lambda cmd, frame: None
    size = sum(i.bytes for i in images[0] if i is not None)
    if size != task.bytes or res.resource(buffer_name).bytes < size:
        raise ScheduleError(f"copy {task.name!r} moves {task.bytes} bytes but {image_name!r} holds "
                            f"{size} (the runner needs 4-byte colour and 2-byte depth pixels)")

    def record(cmd: Any, frame: int) -> None:
        colour, depth = images[res.slot(image_name, frame)]
        buf = res.buffer(buffer_name, dev, res.slot(buffer_name, frame))
        if task.path == "d2h":
            copy_image_to_buffer(cmd, colour, buf, 0)
            if depth is not None:
                copy_image_to_buffer(cmd, depth, buf, colour.bytes)
        else:
            copy_buffer_to_image(cmd, buf, colour, 0)
            if depth is not None:
                copy_buffer_to_image(cmd, buf, depth, colour.bytes)
    return record
