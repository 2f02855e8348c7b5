"""What each task of a FrameProgram does on Vulkan: a recorder for a queue, or host copy parts.

Why one small object per template task: passes and pipelines are built once (slow: shader JIT,
vertex upload) and then recorded every frame into the frame's buffered copy of its resources.
The mapping, kind by kind:
- render (fragment_loop / mesh) -> FragmentLoopTile / MeshShare into the task's `writes[0]`
  (a tile, a half-eye view, a stereo eye: `params` rect, origin, eye);
- filter -> Filter sampling `reads` (at frame offsets `params["read_offsets"]`: the temporal
  pass's history is the previous frame's result);
- particle_update / particle_render -> the particle compute pass and the billboard draw;
- composite_sort_first / _last -> CompositeInto the frame (load), sampling `reads`;
- present -> an image copy of the frame into the displayed image; handoffs -> barriers only;
- copies -> image <-> buffer, image -> image, buffer -> buffer (colour first, then depth; a
  chunk is a range of rows, `params["dst_offset"]` places the picture in a larger image);
- host copies -> numpy copies of byte ranges, one part per memcpy thread (>= chunk_min_bytes);
- the five-step schedule's as-built host loop (CPU tasks the runner can run: `params["runner"]`
  is "host_loop") -> on an application thread of their own, start and join their `threads`
  threads, wait for their inputs (a fence: the reference code's vkQueueWaitIdle) and hand on;
  the command recording they stand for is the submit threads' own.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from mgpusim.model.errors import ScheduleError
from mgpusim.model.geometry import even_split
from mgpusim.model.particle_layout import UPDATE_DT
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, PassTask, Task
from mgpusim.real.passes.particle_update import ParticleUpdate
from mgpusim.real.passes.recorders import (
    CompositeInto,
    Filter,
    FragmentLoopTile,
    MeshShare,
    ParticleDraw,
    copy_image,
    target_over,
)
from mgpusim.real.runner.resources import COLOR_BPP, DEPTH_BPP, Resources
from mgpusim.real.vulkan.copies import copy_buffer, copy_buffer_to_rect, copy_rect, copy_rect_to_buffer
from mgpusim.real.vulkan.device import Gpu, Queue

#: What a task's `choose` answers at submit time (module doc): how many particle updates the
#: step covers, or the vertex-buffer slot to draw (None: nothing uploaded yet).
Choice = int | None


@dataclass
class GpuWork:
    """A queue task: `record(cmd, frame, choice)` on `queue` of `gpu`; `engine` is the trace's
    name. `choose(frame, progress)`, where set, is asked at submit time for what only the run
    can know (which vertex buffer is the newest, how many updates were skipped): its answer is
    passed to `record` and is part of the recorded command buffer's key."""

    task: PassTask | CopyTask
    device: int
    gpu: Gpu
    queue: Queue
    engine: str
    record: Callable[[Any, int, Choice], None]
    nbytes: int
    fallback: bool  # the program asked for a queue this device lacks
    cycle: int  # record(cmd, f, c) depends on f only through f % cycle
    choose: Callable[[int, Any], Choice] | None = None

    def key(self, frame: int, choice: Choice = None) -> tuple[int, int, Choice]:
        """Submissions with one key record the same commands: the Gpu records each command
        buffer once and submits it again (no Python recording in the steady state)."""
        return id(self), frame % self.cycle, choice

    def bound(self, frame: int, choice: Choice = None) -> Callable[[Any], None]:
        """`record` of frame `frame` with `choice`, as the Gpu records it: `bound(cmd)`."""
        record = self.record
        return lambda cmd: record(cmd, frame, choice)


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
        # the simulator's split: HostCopyTask.parts equal parts, the last takes the remainder
        bounds = [0, *itertools.accumulate(even_split(t.bytes, t.parts(self.threads)))]
        return [(dst[a:b], src[a:b]) for a, b in zip(bounds, bounds[1:])]


@dataclass
class CpuWork:
    """A CPU task of the application's thread `thread`: start and join `threads` threads."""

    task: CpuTask
    thread: str
    threads: int


#: `CpuTask.params["runner"]` of the CPU tasks the runner runs (mgpusim/schedules/host_loop.py).
HOST_LOOP = "host_loop"

Work = GpuWork | HostWork | CpuWork


def build_work(task: Task, gpus: list[Gpu], res: Resources, host_threads: int,
               owned: list[Any]) -> Work:
    """The executor of one template task; passes it builds are appended to `owned`."""
    if isinstance(task, HostCopyTask):
        if task.src is None or task.dst is None:
            raise ScheduleError(f"host copy {task.name!r} names no src/dst buffers")
        return HostWork(task, res, host_threads)
    if isinstance(task, CpuTask) and task.params.get("runner") == HOST_LOOP:
        return CpuWork(task, task.thread, task.threads)
    if "unsupported" in task.params:
        raise ScheduleError(f"task {task.name!r}: {task.params['unsupported']}")
    assert not isinstance(task, CpuTask), "CPU tasks are refused above unless the runner runs them"
    q = task.queue
    if not 0 <= q.device < len(gpus):
        raise ScheduleError(f"task {task.name!r} runs on gpu{q.device}; the run has {len(gpus)}")
    gpu = gpus[q.device]
    # one VkQueue per family: a second queue of a family (XR's and AFR's present queue) and a
    # family the device lacks (lavapipe has no copy engine) fall back, and the run records it
    dedicated = (q.family == "graphics" or gpu.has_dedicated(q.family)) and q.index == 0
    engine = q.engine if dedicated else "graphics"
    queue = gpu.queue(q.family)
    choose = None
    if isinstance(task, PassTask):
        record, choose = _pass(task, gpu, res, owned, queue)
        nbytes = 0
    else:
        record, nbytes = _copy(task, res), task.bytes
    return GpuWork(task, q.device, gpu, queue, engine, record, nbytes, not dedicated,
                   res.cycle, choose)


Recorder = Callable[[Any, int, Choice], None]


def _pass(task: PassTask, gpu: Gpu, res: Resources, owned: list[Any],
          queue: Queue) -> tuple[Recorder, Callable[[int, Any], Choice] | None]:
    p = dict(task.params)
    if task.step == "present" or task.kind == "present":
        (src,), (dst,) = task.reads, task.writes
        return (lambda cmd, frame, _c: copy_image(cmd, res.images(src)[res.slot(src, frame)][0],
                                                  res.images(dst)[0][0])), None
    if task.step == "handoff":
        # a queue-family ownership transfer: on one queue family, the barriers Gpu.submit puts
        # around every task are all there is to it
        return (lambda cmd, frame, _c: None), None
    if task.kind == "particle_update":
        return _particle_update(task, gpu, res, owned, p)
    if not task.writes:
        raise ScheduleError(f"pass {task.name!r} ({task.kind}) names no target (writes)")
    out = task.writes[0]
    if task.kind in ("composite_sort_first", "composite_sort_last"):
        return _composite(task, gpu, res, owned, p), None
    targets = [target_over(gpu, c, d, clear=bool(p.get("clear", True)))
               for c, d in res.images(out)]
    try:
        work = _frame_pass(task, gpu, res, targets, p)
    except BaseException:  # the targets are not owned by anything yet
        for t in targets:
            t.destroy()
        raise
    owned.append(work)
    if task.kind == "filter":
        offsets = tuple(p.get("read_offsets", (0,) * len(task.reads)))

        def record(cmd: Any, frame: int, _c: Choice) -> None:
            work.record(cmd, res.slot(out, frame),
                        [res.slot(r, frame + o) for r, o in zip(task.reads, offsets)])
        return record, None
    if task.kind == "particle_render":
        return _particle_draw(task, res, work, queue, out)
    return (lambda cmd, frame, _c: work.record(cmd, res.slot(out, frame))), None


def _frame_pass(task: PassTask, gpu: Gpu, res: Resources, targets: list[Any],
                p: dict[str, Any]) -> Any:
    """The `passes.recorders` object that renders `task` into `targets`."""
    frame_size = tuple(p.get("frame", ()))
    eye = p.get("eye")
    if task.kind == "fragment_loop":
        return FragmentLoopTile(gpu, targets, frame_size, p["rect"], p["origin"],
                                int(p.get("iterations", 0)), eye)
    if task.kind == "mesh":
        return MeshShare(gpu, targets, frame_size, int(p["triangles"]), int(p.get("first", 0)),
                         int(p.get("count", p["triangles"])), rect=p.get("rect"),
                         origin=tuple(p.get("origin", (0, 0))), eye=eye,
                         shape=p.get("shape", "torus"), cull=p.get("cull", "none"))
    if task.kind == "filter":
        inputs = [[c for c, _d in res.images(r)] for r in task.reads]
        return Filter(gpu, targets, frame_size, int(p.get("iterations", 0)), inputs,
                      rect=p.get("rect"), origin=tuple(p.get("origin", (0, 0))))
    if task.kind == "particle_render":
        return ParticleDraw(gpu, targets, int(p["particles"]))
    raise ScheduleError(f"pass {task.name!r}: kind {task.kind!r} has no Vulkan implementation in "
                        f"the runner (fragment_loop, mesh, filter, composite_*, present, "
                        f"particle_update, particle_render, and handoffs)")


def _composite(task: PassTask, gpu: Gpu, res: Resources, owned: list[Any],
               p: dict[str, Any]) -> Recorder:
    out = task.writes[0]
    targets = [target_over(gpu, colour, depth, clear=False) for colour, depth in res.images(out)]
    slots = max(res.resource(r).buffers for r in task.reads) if task.reads else 1
    inputs = [[res.images(r)[s % res.resource(r).buffers] for r in task.reads]
              for s in range(slots)]
    try:
        work: Any = CompositeInto(gpu, targets, tuple(p.get("frame", ())), inputs, p["inputs"],
                                  bool(p["depth"]))
    except BaseException:
        for t in targets:
            t.destroy()
        raise
    owned.append(work)
    return lambda cmd, frame, _c: work.record(cmd, frame % slots, res.slot(out, frame))


def _particle_update(task: PassTask, gpu: Gpu, res: Resources, owned: list[Any],
                     p: dict[str, Any]) -> tuple[Recorder, Callable[[int, Any], Choice] | None]:
    """The update writes buffered copy f % B of its vertex buffer; a skipped update's time
    step is added to the next one that runs (`choose`: 1 + the updates skipped just before)."""
    vertices, state = task.writes
    device = task.queue.device
    bufs = [res.buffer(vertices, device, s) for s in range(res.resource(vertices).buffers)]
    work = ParticleUpdate(gpu, int(p["particles"]), dt=float(p.get("dt", UPDATE_DT)),
                          seed=int(p.get("seed", 0)), vertices=bufs,
                          state_buffer=res.buffer(state, device, 0))
    owned.append(work)
    dt = work.dt

    def record(cmd: Any, frame: int, steps: Choice) -> None:
        work.record(cmd, res.slot(vertices, frame), dt * int(steps or 1))
    if not task.skip_if_busy:
        return record, None
    return record, lambda frame, progress: 1 + progress.skipped_before(task.name, frame)


def _particle_draw(task: PassTask, res: Resources, work: Any, queue: Queue,
                   out: str) -> tuple[Recorder, Callable[[int, Any], Choice] | None]:
    """The draw reads the vertex buffer of frame f's upload (`wait`), or with `params
    ["newest_of"]` (`new_wait`) the newest that task wrote before the draw was submitted."""
    (vertices,) = task.reads
    device = task.queue.device
    writer = task.params.get("newest_of")

    def record(cmd: Any, frame: int, slot: Choice) -> None:
        if writer is None:
            slot = res.slot(vertices, frame)
        elif slot is None:  # nothing uploaded yet: no particles
            work.record(cmd, res.slot(out, frame), None)
            return
        work.record(cmd, res.slot(out, frame), res.buffer(vertices, device, int(slot)))
    if writer is None:
        return record, None

    def choose(frame: int, progress: Any) -> Choice:
        source = progress.newest(writer, frame, queue, task.name)
        return None if source is None else res.slot(vertices, source)
    return record, choose


def _copy(task: CopyTask, res: Resources) -> Recorder:
    """image -> buffer (download), buffer -> image (upload), image -> image, buffer -> buffer;
    `params` give the rows of a chunk, where the picture lands in a larger image, and
    (`images`) several images moved through one buffer, one after the other."""
    if task.path in ("p2p", "group"):
        raise ScheduleError(f"copy {task.name!r}: peer and device-group copies are not supported "
                            f"by the runner (set schedule.path = 'host')")
    if task.src is None or task.dst is None:
        raise ScheduleError(f"copy {task.name!r} names no src/dst resources")
    if task.bytes == 0:  # an empty tile: nothing to move
        return lambda cmd, frame, _c: None
    src, dst = res.resource(task.src), res.resource(task.dst)
    if src.kind == "buffer" and dst.kind == "buffer":
        return _buffer_copy(task, res)
    if src.kind == "image" and dst.kind == "image":
        return _image_copy(task, res)
    down = src.kind == "image"
    images = [res.resource(n) for n in task.params.get("images", (task.src if down else task.dst,))]
    buffer = dst if down else src
    parts, offset = [], 0
    for image in images:  # (image, its rectangle, buffer offset of its colour, of its depth)
        rect, colour, depth = _region(task, image, image.depth)
        parts.append((image.name, rect, offset, offset + colour if depth else None))
        offset += colour + depth
    _check_bytes(task, offset)
    dev = task.queue.device

    def record(cmd: Any, frame: int, _c: Choice) -> None:
        buf = res.buffer(buffer.name, dev, res.slot(buffer.name, frame))
        for name, rect, at_colour, at_depth in parts:
            pair = res.images(name)[res.slot(name, frame)]
            for image, at in ((pair[0], at_colour), (pair[1], at_depth)):
                if at is None:
                    continue
                assert image is not None  # a depth offset only for an image with depth
                if down:
                    copy_rect_to_buffer(cmd, image, buf, at, rect)
                else:
                    copy_buffer_to_rect(cmd, buf, at, image, rect)
    return record


def _region(task: CopyTask, image: Any, has_depth: bool) -> tuple[tuple[int, int, int, int], int, int]:
    """The rectangle of `image` a copy touches (the chunk's rows of the moved picture, placed at
    `dst_offset` when the image is the destination), and its colour and depth bytes."""
    width, height = task.params.get("extent", (image.width, image.height))
    y0, rows = task.params.get("rows", (0, height))
    dx, dy = task.params.get("dst_offset", (0, 0)) if image.name == task.dst else (0, 0)
    depth = bool(task.params.get("depth", has_depth))
    return (dx, dy + y0, width, rows), width * rows * COLOR_BPP, (width * rows * DEPTH_BPP
                                                                 if depth else 0)


def _check_bytes(task: CopyTask, size: int) -> None:
    if size != task.bytes:
        raise ScheduleError(f"copy {task.name!r} moves {task.bytes} bytes but its pixels hold "
                            f"{size} (the runner's images have 4-byte colour and 2-byte depth "
                            f"pixels)")


def _image_copy(task: CopyTask, res: Resources) -> Recorder:
    """Image -> image on one device (XR's own view into the two-eye image)."""
    src, dst = res.resource(task.src or ""), res.resource(task.dst or "")
    (_x, y, width, rows), colour, depth = _region(task, src, src.depth and dst.depth)
    (dx, dy, _w, _r), _c, _d = _region(task, dst, src.depth and dst.depth)
    _check_bytes(task, colour + depth)

    def record(cmd: Any, frame: int, _c: Choice) -> None:
        s = res.images(src.name)[res.slot(src.name, frame)]
        d = res.images(dst.name)[res.slot(dst.name, frame)]
        for k in range(2 if depth else 1):
            source, target = s[k], d[k]
            assert source is not None and target is not None  # depth: both images have it
            copy_rect(cmd, source, target, (0, y), (dx, dy), (width, rows))
    return record


def _buffer_copy(task: CopyTask, res: Resources) -> Recorder:
    """Buffer -> buffer of the task's bytes (the particles' vertex buffer on its way)."""
    src, dst = res.resource(task.src or ""), res.resource(task.dst or "")
    if task.bytes > min(src.bytes, dst.bytes):
        raise ScheduleError(f"copy {task.name!r} moves {task.bytes} bytes between buffers of "
                            f"{src.bytes} and {dst.bytes} bytes")
    dev = task.queue.device

    def record(cmd: Any, frame: int, _c: Choice) -> None:
        copy_buffer(cmd, res.buffer(src.name, dev, res.slot(src.name, frame)),
                    res.buffer(dst.name, dev, res.slot(dst.name, frame)), task.bytes)
    return record
