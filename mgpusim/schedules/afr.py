"""Alternate-frame rendering (AFR) for N GPUs.

Frame f runs whole on GPU f % N (one template per GPU). A secondary's finished image crosses
to GPU 0, which presents every frame on its present queue (a second graphics queue when it
has one, so presenting never delays GPU 0's own rendering). With a `temporal_pass`, frame f's
pass of that name reads frame f-1's result, which is copied from GPU (f-1) % N first
(F0->F1, F1->F2, ...): the copies that leave idle gaps on both graphics queues in the talk.
Frame pacing is not averaged away: every present is in the frames table and the summary's
frame_time_jitter_ms / min / max come from the individual periods. With `pace_us` the engine
paces its presents (frame metering): frame f's present is held until `pace_us` after frame
f-1's was released, so N GPUs that finish their frames together still present at an even
cadence (two tasks of the application's `pacer` thread, which sleeps: `pace.hold` releases
the present once the frame is ready and the previous `pace.gap` has run out; `pace.gap`, the
cadence's timer, starts at that release).
"""
from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import Scene
from mgpusim.model.tasks import CpuTask, Dep, PassTask, QueueRef, Resource, Task
from mgpusim.schedules.base import Footprint, FrameProgram, chain_passes, present_task
from mgpusim.schedules.binding import Bindings, bind_crossing
from mgpusim.schedules.crossing import COPY_OPTIONS, Route, cross
from mgpusim.schedules.pass_io import bind_full_frame, filter_reads, pass_image, reads_own_output
from mgpusim.schedules.registry import Option, ScheduleConfig, register

OPTIONS = {
    **COPY_OPTIONS,
    "temporal_pass": Option(str, "", "name of the scene pass that reads the previous frame's "
                            "result ('' = ideal AFR, no inter-frame dependency)"),
    "history_bytes": Option(int, 0, "bytes of the previous frame's result the temporal pass "
                            "reads (0 = one full-frame colour target)", minimum=0,
                            maximum=L.MAX_BYTES, why=L.WHY_BYTES),
    "present_queue": Option(str, "separate", "'separate': present on GPU 0's second graphics "
                            "queue when it has one; 'graphics': on its main graphics queue",
                            choices=("separate", "graphics")),
    "pace_us": Option(float, 0.0, "frame pacing: hold each present until this long (us) after "
                      "the previous one was released, an even cadence (frame metering; simulated "
                      "only); 0 = present each frame as soon as it is ready", minimum=0.0,
                      maximum=L.MAX_TASK_NS / 1000, why="a task's time bound"),
}

#: The application's thread that paces the presents (`pace_us`): it sleeps between them.
PACER_THREAD = "pacer"


def present_queue(profile: HardwareProfile, policy: str) -> QueueRef:
    """GPU 0's queue for presents: a dedicated graphics queue if asked for and present."""
    if policy == "separate" and profile.gpus[0].has_queue("graphics", 1):
        return QueueRef(0, "graphics", 1)
    return QueueRef(0, "graphics")


@register("afr", "Alternate-frame rendering on N GPUs; optional temporal (inter-frame) dependency",
          OPTIONS)
def build_afr(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    n, route = cfg.gpus, Route.from_options(cfg.opt)
    temporal = _temporal_name(cfg, scene)
    history = cfg.opt("history_bytes") or scene.color_bytes
    templates = tuple(tuple(_phase(p, cfg, scene, profile, route, temporal, history))
                      for p in range(n))
    templates, resources = _bind(templates, cfg, scene, temporal)
    held = history if temporal and n > 1 else 0
    record = {"temporal_pass": temporal or "", "history_bytes": held,
              "image_bytes": scene.color_bytes,
              "present_queue": str(present_queue(profile, cfg.opt("present_queue")))}
    return FrameProgram(cfg.name, n, cfg.frames, cfg.warmup_frames, templates,
                        record=MappingProxyType(record), footprints=_footprints(scene, n, held),
                        resources=resources)


def _bind(templates: tuple[tuple[Task, ...], ...], cfg: ScheduleConfig, scene: Scene,
          temporal: str | None) -> tuple[tuple[tuple[Task, ...], ...], tuple[Resource, ...]]:
    """What every task reads and writes on the Vulkan runner.

    GPU p renders pass X into `gpu{p}.pass.X`; its finished frame crosses to `gpu0.from{p}`,
    which present copies to `gpu0.display` (GPU 0's own frames: its last pass's image). The
    temporal pass samples the passes before it and, as its last input, the history
    `gpu{p}.history`, which the previous frame's GPU sent (one GPU: its own result of the
    previous frame, double-buffered). Staging buffers of a crossing from GPU p are used every
    N frames; N * ceil((F + 1) / N) copies (F frames in flight) keep a download from
    overwriting one that the history's or frame's reader has not read yet."""
    n, b = cfg.gpus, Bindings()
    w, h = scene.width, scene.height
    last = f"pass.{scene.passes[-1].name}"
    staging = n * -(-(cfg.frames_in_flight + 1) // n)
    b.image("gpu0.display", 0, w, h)
    out = []
    for p, tasks in enumerate(templates):
        crossed: dict[str, Task] = {}
        hist = [t for t in tasks if t.name.startswith("hist.")]
        if hist and temporal:
            dst = b.image(f"gpu{(p + 1) % n}.history", (p + 1) % n, w, h)
            src = f"gpu{p}.pass.{temporal.removeprefix('render.')}"
            crossed.update((t.name, t) for t in bind_crossing(
                hist, b, src, dst, staging=f"hist{p}", buffers=staging, params=COLOUR_ONLY))
        sent = [t for t in tasks if t.name.startswith("out.")]
        if sent:
            dst = b.image(f"gpu0.from{p}", 0, w, h)
            crossed.update((t.name, t) for t in bind_crossing(
                sent, b, f"gpu{p}.{last}", dst, staging=f"out{p}", buffers=staging,
                params=COLOUR_ONLY))
        bound: list[Task] = []
        for task in tasks:
            if task.name in crossed:
                bound.append(crossed[task.name])
            elif isinstance(task, PassTask) and task.step == "render":
                bound.append(_bind_render(task, p, n, scene, temporal, b))
            elif task.name == "present":
                src = f"gpu0.{last}" if p == 0 else f"gpu0.from{p}"
                assert isinstance(task, PassTask)
                bound.append(replace(task, reads=(src,), writes=("gpu0.display",)))
            else:
                bound.append(task)
        out.append(tuple(bound))
    return tuple(out), b.resources()


#: The frame and the history cross GPUs as colour only (what the schedule counts).
COLOUR_ONLY = MappingProxyType({"depth": False})


def _bind_render(task: PassTask, p: int, n: int, scene: Scene, temporal: str | None,
                 b: Bindings) -> PassTask:
    """A pass of GPU p's frame into `gpu{p}.pass.X`; a filter samples its inputs there."""
    index = next(i for i, s in enumerate(scene.passes) if task.name == f"render.{s.name}")
    spec = scene.passes[index]
    is_temporal = task.name == temporal
    own = not is_temporal and reads_own_output(scene.passes, index)
    one_gpu_history = (is_temporal or own) and n == 1 and spec.kind == "filter"
    target = pass_image(b, f"gpu{p}.pass.{spec.name}", p, scene, spec,
                        buffers=2 if one_gpu_history else 1)
    if spec.kind != "filter":
        return bind_full_frame(task, spec, scene, target)
    if own and n > 1:
        why = (f"filter pass {spec.name!r} samples its previous output, which another GPU "
               f"rendered under AFR: set schedule.temporal_pass = {spec.name!r}")
        return bind_full_frame(task, spec, scene, target, why)
    if not is_temporal:
        return bind_full_frame(task, spec, scene, target,
                               *filter_reads(scene.passes, index, lambda s: f"gpu{p}.pass.{s}"))
    # the temporal pass: the passes before it, then the history as its last input
    k = int(spec.param("inputs", 2))
    if not 2 <= k <= index + 1:
        why = (f"temporal filter pass {spec.name!r} samples {k - 1} passes before it and the "
               f"history; set inputs to 2..{index + 1}")
        return bind_full_frame(task, spec, scene, target, why)
    before = [f"gpu{p}.pass.{s.name}" for s in scene.passes[index - (k - 1):index]]
    if n == 1:
        return bind_full_frame(task, spec, scene, target, before + [target],
                               [0] * len(before) + [-1])
    history = b.image(f"gpu{p}.history", p, scene.width, scene.height)
    return bind_full_frame(task, spec, scene, target, before + [history])


def _footprints(scene: Scene, n: int, history: int) -> tuple[Footprint, ...]:
    """Every GPU holds the whole data set, a full target and the history it reads; GPU 0 also
    receives the secondaries' finished images."""
    full = scene.color_bytes + scene.depth_bytes
    return tuple(Footprint(i, 1.0, full + history, (n - 1) * scene.color_bytes if i == 0 else 0)
                 for i in range(n))


def _temporal_name(cfg: ScheduleConfig, scene: Scene) -> str | None:
    name = cfg.opt("temporal_pass")
    if not name:
        return None
    if name not in {p.name for p in scene.passes}:
        raise InputError(f"no scene pass named {name!r} (passes: {[p.name for p in scene.passes]})",
                         field="schedule.temporal_pass")
    return f"render.{name}"


def _phase(p: int, cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile, route: Route,
           temporal: str | None, history: int) -> list[Task]:
    """The tasks of a frame rendered on GPU p."""
    n, fif = cfg.gpus, cfg.frames_in_flight
    tasks: list[Task] = []
    history_in = None
    if temporal and n > 1:
        prev = (p - 1) % n
        history_in = cross("hist", profile, prev, p, history, (), route)[-1].name
    out: list[Task] = []
    if p != 0:
        out = cross("out", profile, p, 0, scene.color_bytes, (), route, dst_deps=(Dep("present", -n),))
    # a secondary's render target is free again once its previous frame's image was read out
    first_deps = (Dep("present", -fif),) + ((Dep(out[0].name, -n),) if out else ())
    tasks.extend(_renders(p, scene, first_deps, temporal, history_in))
    last = tasks[-1].name
    if temporal and n > 1:
        # the next frame's GPU reads this history; its buffer is free once that GPU's
        # previous temporal pass (frame f+1-n) has run
        tasks.extend(cross("hist", profile, p, (p + 1) % n, history, (Dep(temporal),), route,
                           dst_deps=(Dep(temporal, -(n - 1)),)))
    if out:
        out = cross("out", profile, p, 0, scene.color_bytes, (Dep(last),), route,
                    dst_deps=(Dep("present", -n),))
        tasks.extend(out)
        last = out[-1].name
    if cfg.opt("pace_us"):
        hold, gap = pacing(last, cfg.opt("pace_us"))
        tasks += [hold, gap]
        last = hold.name  # the present waits for the pacer's release
    tasks.append(present_task(present_queue(profile, cfg.opt("present_queue")), scene.pixels, last))
    return tasks


def pacing(ready: str, pace_us: float) -> tuple[CpuTask, CpuTask]:
    """The pacer's two tasks of a frame: the hold that releases its present once `ready` has
    ended and the previous frame's gap has run out, then this frame's gap (`pace_us`), which
    the next frame's hold waits for. Both sleep (idle): pacing takes no core."""
    hold = CpuTask("pace.hold", "pace", PACER_THREAD, deps=(Dep(ready), Dep("pace.gap", -1)), idle=True,
                   params=_SIM_ONLY)
    gap = CpuTask("pace.gap", "pace", PACER_THREAD, fixed_ns=pace_us * 1000, deps=(Dep(hold.name),),
                  idle=True, params=_SIM_ONLY)
    return hold, gap


def with_pace(program: FrameProgram, pace_us: float) -> FrameProgram:
    """An evenly paced AFR program at another cadence: every frame's `pace.gap` lasting
    `pace_us`, as :func:`build_afr` makes it (nothing else of the program depends on the
    cadence: the pacer's tasks come last before the present, and the CPU frame and vsync
    leave them as they are; a test compares it with the program built at that cadence). Why:
    `mgpusim advise` tries every AFR option at four cadences, and building the program again
    for each costs more than its run. `program` must be paced (have the pacer's tasks)."""
    if not any(t.name == "pace.gap" for t in program.templates[0]):
        raise ValueError("not an evenly paced AFR program: it has no pace.gap task")
    fixed = pace_us * 1000
    templates = tuple(tuple(replace(t, fixed_ns=fixed) if t.name == "pace.gap" and isinstance(t, CpuTask) else t
                            for t in tasks) for tasks in program.templates)
    return replace(program, templates=templates)


_SIM_ONLY = MappingProxyType({"unsupported": "frame pacing (schedule.pace_us) is simulated only: "
                                             "the Vulkan runner presents into an offscreen image"})


def _renders(gpu: int, scene: Scene, first_deps: tuple[Dep, ...], temporal: str | None,
             history_in: str | None) -> list[PassTask]:
    """The whole frame's passes on one GPU; the temporal pass also waits for the history."""
    out = chain_passes(scene.passes, QueueRef(gpu, "graphics"), first_deps, scene.pixels,
                       lambda spec: f"render.{spec.name}", place=scene.whole_frame)
    if history_in is None:
        return out
    return [replace(t, deps=t.deps + (Dep(history_in, -1),)) if t.name == temporal else t
            for t in out]
