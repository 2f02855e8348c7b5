"""Frame pipelining: a frame's first passes on GPU 1, the rest on GPU 0.

The scene's passes [0, split_at) run on GPU 1; their outputs (each pass's `output_bytes`)
cross to GPU 0 (through host memory, or over a peer link), where the remaining passes run and
the frame is presented. GPU 1 starts frame f+1 while GPU 0 finishes frame f, so the GPUs and
copy engines form a pipeline: copies cost latency, not frame rate, unless they take longer
than the work. Copies can be issued per pass (as soon as each output is ready) and split into
`chunks` pieces, so the destination's upload of one piece overlaps the download of the next
and the rest of the frame's work. Intermediate buffers are multi-buffered (`buffers`).
"""
from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

from .. import limits as L
from ..errors import InputError
from ..profile import HardwareProfile
from ..scene import PassSpec, Scene
from ..tasks import Dep, PassTask, QueueRef, Task
from .base import (Footprint, FrameProgram, Option, ScheduleConfig, chain_passes, even_split,
                   present_task, register)
from .crossing import COPY_OPTIONS, Route, cross

OPTIONS = {
    **COPY_OPTIONS,
    "split_at": Option(int, 1, "passes [0, split_at) run on GPU 1, the rest on GPU 0 "
                       "(0 = everything on GPU 0)", minimum=0),
    "copy_granularity": Option(str, "pass", "'pass': copy each pass's output when that pass "
                               "ends; 'frame': one copy after GPU 1's last pass",
                               choices=("pass", "frame")),
    "chunks": Option(int, 1, "split every copy into this many equal pieces", minimum=1,
                     maximum=L.MAX_CHUNKS, why=L.WHY_ALLOC),
    "buffers": Option(int, 2, "copies of the intermediate buffers on each GPU", minimum=1,
                      maximum=L.MAX_BUFFERS, why=L.WHY_ALLOC),
}


@register("pipelining", "Frame pipelining on 2 GPUs: first passes on GPU 1, the rest and present on GPU 0",
          OPTIONS)
def build_pipelining(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    split = _split(cfg, scene)
    route = Route.from_options(cfg.opt)
    first, rest = scene.passes[:split], scene.passes[split:]
    tasks: list[Task] = []
    arrivals: list[str] = []
    buffers, fif = cfg.opt("buffers"), cfg.frames_in_flight
    if first:
        renders = _passes(1, first, scene, (Dep("present", -fif),))
        copies, arrivals = _copies(cfg, scene, profile, route, first)
        # GPU 1 may overwrite its outputs once the copies of frame f-buffers have read them
        reads = tuple(Dep(c.name, -buffers) for c in copies if c.step in ("d2h", "p2p"))
        renders[0] = _with_deps(renders[0], reads)
        tasks.extend(_interleave(renders, copies))
    gate = (Dep("present", -fif),) + tuple(Dep(a) for a in arrivals)
    tasks.extend(_passes(0, rest, scene, gate))
    last = tasks[-1].name if rest else arrivals[-1]
    tasks.append(present_task(QueueRef(0, "graphics"), scene.pixels, last))
    moved = sum(_output_bytes(p) for p in first)
    record = {"split_at": split, "gpu1_passes": tuple(p.name for p in first),
              "bytes_per_frame": moved, "chunks": cfg.opt("chunks"), "buffers": buffers,
              "copy_granularity": cfg.opt("copy_granularity")}
    return FrameProgram(cfg.name, cfg.gpus, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record),
                        footprints=_footprints(scene, cfg.gpus, buffers * moved))


def _footprints(scene: Scene, n: int, intermediate: int) -> tuple[Footprint, ...]:
    """GPU 0 holds the data set, a full target and the arriving intermediate buffers; GPU 1
    the intermediate results it renders."""
    primary = Footprint(0, 1.0, scene.color_bytes + scene.depth_bytes, intermediate)
    return (primary,) + ((Footprint(1, 1.0, intermediate, 0),) if n > 1 else ())


def _split(cfg: ScheduleConfig, scene: Scene) -> int:
    if cfg.gpus > 2:
        raise InputError(f"pipelining runs on 1 or 2 GPUs, got {cfg.gpus}", field="schedule.gpus")
    split = 0 if cfg.gpus == 1 else cfg.opt("split_at")
    if split > len(scene.passes):
        raise InputError(f"split_at = {split} but the scene has {len(scene.passes)} passes",
                         field="schedule.split_at")
    return split


def _output_bytes(spec: PassSpec) -> int:
    return int(spec.param("output_bytes"))


def _passes(gpu: int, specs: tuple[PassSpec, ...], scene: Scene, first_deps: tuple[Dep, ...]) -> list[PassTask]:
    return chain_passes(specs, QueueRef(gpu, "graphics"), first_deps, scene.pixels,
                        lambda spec: f"render.{spec.name}")


def _copies(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile, route: Route,
            first: tuple[PassSpec, ...]) -> tuple[list[Task], list[str]]:
    """The crossing tasks, and the names whose end means a piece has arrived on GPU 0."""
    if cfg.opt("copy_granularity") == "frame":
        groups = [("out", sum(_output_bytes(p) for p in first), f"render.{first[-1].name}")]
    else:
        groups = [(f"out.{p.name}", _output_bytes(p), f"render.{p.name}") for p in first]
    tasks: list[Task] = []
    arrivals: list[str] = []
    chunks, buffers = cfg.opt("chunks"), cfg.opt("buffers")
    for prefix, nbytes, after in groups:
        for c, size in enumerate(even_split(nbytes, chunks)):
            name = prefix if chunks == 1 else f"{prefix}#{c}"
            piece = cross(name, profile, 1, 0, size, (Dep(after),), route,
                          dst_deps=(Dep(f"render.{_gpu0_first(cfg, scene)}", -buffers),)
                          if _gpu0_first(cfg, scene) else (Dep("present", -buffers),))
            tasks.extend(piece)
            arrivals.append(piece[-1].name)
    return tasks, arrivals


def _gpu0_first(cfg: ScheduleConfig, scene: Scene) -> str | None:
    """The first pass on GPU 0 (it consumes the intermediate results), if any."""
    split = cfg.opt("split_at")
    return scene.passes[split].name if split < len(scene.passes) else None


def _with_deps(task: PassTask, extra: tuple[Dep, ...]) -> PassTask:
    return replace(task, deps=task.deps + extra)


def _interleave(renders: list[PassTask], copies: list[Task]) -> list[Task]:
    """Submission order: each pass followed by the copies that read its output, so copies
    recorded on the graphics queue run between passes rather than after all of them."""
    after: dict[str, list[Task]] = {}
    rest: list[Task] = []
    names = {r.name for r in renders}
    for c in copies:  # one pass over the copies: linear in chunks, not quadratic
        if c.deps and c.deps[0].task in names:
            after.setdefault(c.deps[0].task, []).append(c)
        else:
            rest.append(c)
    out: list[Task] = []
    for r in renders:
        out.append(r)
        out.extend(after.get(r.name, ()))
    return out + rest
