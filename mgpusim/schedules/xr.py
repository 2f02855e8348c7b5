"""XR multi-GPU stereo, after NVIDIA's `xr_multi_gpu` Vulkan sample.

The scene's width x height is ONE eye. With 2 views each GPU renders one eye; with 4 views
each renders half an eye (the eye's columns split in two). A frame, in four steps:
(1) each GPU renders its view into device-local colour + depth on its graphics queue and
releases the images to the transfer queue family (a queue-family hand-off, `handoff_us`);
(2) the first GPU waits for all; (3) its dedicated transfer queue copies every view (its own
d2d, the others' over a peer link or through host memory) into the final image; (4) the
final image is handed to a separate present queue (a second graphics queue) and presented,
so GPU 0's main graphics queue can start the next frame.
- weak scaling: frame f+1's rendering starts after frame f's present;
- strong scaling: it starts as soon as every GPU finished rendering frame f (the transfer is
  hidden); view targets are then multi-buffered (`buffers`) so rendering never overwrites an
  image the transfer queue still reads. At most `frames_in_flight` (<= 3) frames in flight.
- mode 'simulated' runs every view on the first GPU (one graphics queue, views in turn) with
  d2d copies: the sample's single-GPU stand-in for a multi-GPU machine.
Latency (start of rendering to present) and frame time are reported separately as always.
"""
from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType
from typing import Any

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import Placement, even_split
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import Dep, PassTask, QueueRef, Resource, Task
from mgpusim.model.work_terms import pass_work
from mgpusim.schedules.afr import present_queue
from mgpusim.schedules.base import Footprint, FrameProgram, chain_passes, present_task, queue_or_graphics
from mgpusim.schedules.binding import Bindings, bind_crossing
from mgpusim.schedules.crossing import PATHS, Route, cross
from mgpusim.schedules.pass_io import simulated_only
from mgpusim.schedules.registry import Option, ScheduleConfig, register

MAX_FRAMES_IN_FLIGHT = 3

OPTIONS = {
    "scaling": Option(str, "weak", "'weak': next frame after the present; 'strong': next frame "
                      "as soon as all GPUs finished rendering", choices=("weak", "strong")),
    "mode": Option(str, "multi", "'multi': one view per GPU; 'simulated': every view on GPU 0",
                   choices=("multi", "simulated")),
    "views": Option(int, 0, "2 (one eye per view) or 4 (half an eye); 0 = one per GPU",
                    choices=(0, 2, 4)),
    "path": Option(str, "auto", "how views reach GPU 0: 'peer', 'host', 'group' (device to "
                   "device over PCIe in a device group, as the sample) or 'auto' (peer if the "
                   "profile has a link)", choices=PATHS),
    "host_copy": Option(bool, False, "host-to-host memcpy between staging buffers on the host path"),
    "handoff_us": Option(float, 0.0, "cost of one queue-family ownership hand-off (a barrier), "
                         "in reference microseconds (a 'timed' pass)", minimum=0.0,
                         maximum=L.MAX_TASK_NS / 1000, why=L.WHY_TIME),
    "buffers": Option(int, 2, "view render targets per GPU under strong scaling", minimum=1,
                      maximum=L.MAX_BUFFERS, why=L.WHY_ALLOC),
}


@register("xr", "XR stereo: 2 GPUs (an eye each) or 4 (half an eye each), weak or strong scaling",
          OPTIONS)
def build_xr(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    views, simulated = _views(cfg)
    widths = even_split(scene.width, views // 2)
    pixels = [widths[v % len(widths)] * scene.height for v in range(views)]
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    route = Route("transfer", cfg.opt("path"), cfg.opt("host_copy"))
    gpu_of = [0 if simulated else v for v in range(views)]
    tasks: list[Task] = []
    for v in range(views):
        tasks.extend(_render_view(v, gpu_of, scene, pixels[v], cfg))
    arrivals = []
    for v in range(views):
        moved = cross(f"view{v}", profile, gpu_of[v], 0, pixels[v] * bpp,
                      (Dep(f"release{v}"),), route, pull=True)
        tasks.extend(moved)
        arrivals.append(moved[-1].name)
    pq = present_queue(profile, "separate")
    tasks.append(_handoff("acquire", pq, cfg, tuple(Dep(a) for a in arrivals)))
    tasks.append(present_task(pq, 2 * scene.pixels, "acquire"))
    record = {"views": views, "mode": cfg.opt("mode"), "scaling": cfg.opt("scaling"),
              "view_pixels": tuple(pixels), "buffers": cfg.opt("buffers"),
              "bytes_per_frame": sum(pixels) * bpp,
              "transfer_queue": str(queue_or_graphics(profile, 0, "transfer")),
              "present_queue": str(pq)}
    tasks, resources = _bind(tasks, cfg, scene, gpu_of, widths)
    return FrameProgram(cfg.name, cfg.gpus, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), resources=resources,
                        footprints=_footprints(cfg, scene, pixels, simulated))


def _bind(tasks: list[Task], cfg: ScheduleConfig, scene: Scene, gpu_of: list[int],
          widths: list[int]) -> tuple[list[Task], tuple[Resource, ...]]:
    """What every task reads and writes on the Vulkan runner.

    View v is eye v // (V/2), columns [x0, x0 + width) of it: its passes render that part of
    the eye's frame (the whole eye's viewport shifted, as sort-first tiles, so the pixels equal
    a whole-eye render) with the eye's stereo camera into `gpu{g}.view{v}` (colour + depth;
    `buffers` copies under strong scaling). The transfer queue copies every view into its place
    in `gpu0.final` (both eyes side by side), which present copies to `gpu0.display`."""
    b, views = Bindings(), len(gpu_of)
    w, h, per_eye = scene.width, scene.height, views // 2
    depth = scene.depth_bytes_per_pixel > 0
    buffers = cfg.opt("buffers") if cfg.opt("scaling") == "strong" else 1
    b.image("gpu0.final", 0, 2 * w, h, depth=depth)
    b.image("gpu0.display", 0, 2 * w, h)
    place = []
    crossed: dict[str, Task] = {}
    for v in range(views):
        eye, part = divmod(v, per_eye)
        x0 = sum(widths[:part])
        place.append((eye, x0, widths[part]))
        target = b.image(f"gpu{gpu_of[v]}.view{v}", gpu_of[v], widths[part], h, depth=depth,
                         buffers=buffers)
        piece = [t for t in tasks if t.name.startswith(f"view{v}.")]
        crossed.update((t.name, t) for t in bind_crossing(
            piece, b, target, "gpu0.final", staging=f"view{v}", buffers=buffers,
            params={"dst_offset": (eye * w + x0, 0), "extent": (widths[part], h)}))
    out: list[Task] = []
    for task in tasks:
        if task.name in crossed:
            out.append(crossed[task.name])
        elif isinstance(task, PassTask) and task.step == "render":
            v = int(task.name.removeprefix("render").partition(".")[0])
            out.append(_bind_view(task, scene, v, gpu_of[v], place[v]))
        elif task.name == "present":
            assert isinstance(task, PassTask)
            out.append(replace(task, reads=("gpu0.final",), writes=("gpu0.display",)))
        else:
            out.append(task)
    return out, b.resources()


def _bind_view(task: PassTask, scene: Scene, v: int, gpu: int,
               place: tuple[int, int, int]) -> PassTask:
    """View v's pass: its columns of the eye, the eye's camera; the first pass clears."""
    eye, x0, width = place
    spec = next(s for s in scene.passes if task.name == f"render{v}.{s.name}")
    params: dict[str, Any] = {"frame": (scene.width, scene.height),
                              "rect": (x0, 0, width, scene.height), "origin": (x0, 0), "eye": eye,
                              "clear": spec is scene.passes[0], **spec.params, **spec.options}
    if "triangles" in spec.params:
        params.update(triangles=int(spec.params["triangles"]), first=0,
                      count=int(spec.params["triangles"]))
    if "iterations" in spec.params:
        params["iterations"] = int(spec.params["iterations"])
    if spec.kind not in ("fragment_loop", "mesh"):
        params["unsupported"] = (f"XR views run fragment_loop and mesh passes on the Vulkan "
                                 f"runner, not {spec.kind!r} ({spec.name!r})")
    params.update(simulated_only(spec))
    return replace(task, writes=(f"gpu{gpu}.view{v}",), params=MappingProxyType(params))


def _footprints(cfg: ScheduleConfig, scene: Scene, views: list[int],
                simulated: bool) -> tuple[Footprint, ...]:
    """Each GPU its view targets (multi-buffered under strong scaling); GPU 0 also the final
    two-eye image and the views that arrive from the others."""
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    buffers = cfg.opt("buffers") if cfg.opt("scaling") == "strong" else 1
    final = 2 * scene.pixels * scene.color_bytes_per_pixel
    if simulated or cfg.gpus == 1:
        return (Footprint(0, 1.0, buffers * sum(views) * bpp + final, 0),)
    primary = Footprint(0, 1.0, buffers * views[0] * bpp + final, sum(views[1:]) * bpp)
    return (primary,) + tuple(Footprint(i, 1.0, buffers * views[i] * bpp, 0)
                              for i in range(1, len(views)))


def _views(cfg: ScheduleConfig) -> tuple[int, bool]:
    simulated = cfg.opt("mode") == "simulated"
    views = cfg.opt("views") or cfg.gpus
    if views not in (2, 4):
        raise InputError(f"XR renders 2 or 4 views, got {views} (set schedule.views or gpus)",
                         field="schedule.views")
    if not simulated and views != cfg.gpus:
        raise InputError(f"mode 'multi' renders one view per GPU: views = {views} but gpus = "
                         f"{cfg.gpus} (use mode = 'simulated' to run them all on GPU 0)",
                         field="schedule.views")
    if cfg.frames_in_flight > MAX_FRAMES_IN_FLIGHT:
        raise InputError(f"the XR sample keeps at most {MAX_FRAMES_IN_FLIGHT} frames in flight, "
                         f"got {cfg.frames_in_flight}", field="schedule.frames_in_flight")
    return views, simulated


def _render_view(v: int, gpu_of: list[int], scene: Scene, pixels: int,
                 cfg: ScheduleConfig) -> list[PassTask]:
    """View v's passes on its GPU's graphics queue, then the release to the transfer queue."""
    queue = QueueRef(gpu_of[v], "graphics")
    out = chain_passes(scene.passes, queue, _frame_gate(v, len(gpu_of), scene, cfg), pixels,
                       lambda spec: f"render{v}.{spec.name}", place=_place(v, scene, len(gpu_of)))
    out.append(_handoff(f"release{v}", queue, cfg, (Dep(out[-1].name),)))
    return out


def _place(v: int, scene: Scene, views: int) -> Placement:
    """View v draws its eye's columns `part` (views of one eye split it into equal columns)
    with that eye's camera: the runner's layout (`_bind`)."""
    per_eye = views // 2
    eye, part = divmod(v, per_eye)
    widths = even_split(scene.width, per_eye)
    return Placement((scene.width, scene.height), (sum(widths[:part]), 0, widths[part], scene.height),
                     eye=eye)


def _frame_gate(v: int, views: int, scene: Scene, cfg: ScheduleConfig) -> tuple[Dep, ...]:
    """When view v of frame f may start: weak after present f-1; strong after every view of
    f-1 rendered and its own target of frame f-buffers was copied out."""
    fif = cfg.frames_in_flight
    if cfg.opt("scaling") == "weak":
        return (Dep("present", -1),)
    last = scene.passes[-1].name
    rendered = tuple(Dep(f"render{w}.{last}", -1) for w in range(views))
    return rendered + (Dep("present", -fif), Dep("acquire", -cfg.opt("buffers")))


def _handoff(name: str, queue: QueueRef, cfg: ScheduleConfig, deps: tuple[Dep, ...]) -> PassTask:
    """A queue-family ownership transfer (release or acquire barrier) as a short timed pass."""
    spec = PassSpec(name, "timed", MappingProxyType({"duration_ms": cfg.opt("handoff_us") / 1000}))
    return PassTask(name, "handoff", queue, "timed", MappingProxyType(pass_work(spec, 0)), deps)
