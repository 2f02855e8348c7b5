"""Particle simulation offloaded to a secondary GPU.

The scene's passes (shadow, geometry, SSAO, deferred lighting, ...) run in order on the
primary's graphics queue; the particles are drawn by a `particle_render` pass right after the
pass named `draw_after`. The particle update (a compute pass) runs on the secondary GPU's
compute queue (its graphics queue if it has none) or, with `particle_gpu = 0`, on the
primary's compute queue in parallel with the shadow pass. From a secondary, the vertex
buffer (192 B per particle: 6 vertices x position + uv) is downloaded to the host, copied
from the readback to the upload buffer by the CPU, and uploaded to the primary.
- policy 'wait': the particle draw of frame f waits for frame f's update and upload.
- policy 'new_wait': the CPU never blocks on the particle GPU. When the previous update (or
  its copies) has not finished at submit time, this frame's update and its copies are
  skipped (the skipped time accumulates into the next dt) and the draw uses the last
  uploaded vertex buffer, so particles tick at a lower rate than frames. The summary's
  task_rates_hz gives the update rate beside the frame rate.
Vertex buffers are double-buffered on both GPUs.
"""
from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError
from mgpusim.model.particle_layout import CALC_BYTES, STATE_BYTES, UPDATE_DT, VERTEX_BYTES
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import CpuTask, Dep, PassTask, QueueRef, Resource, Task
from mgpusim.schedules.base import MAIN_THREAD, Footprint, FrameProgram, chain_passes, present_task, queue_or_graphics
from mgpusim.schedules.binding import Bindings, bind_crossing
from mgpusim.schedules.crossing import Route, cross
from mgpusim.schedules.pass_io import bind_full_frame, filter_reads, pass_image, reads_own_output
from mgpusim.schedules.registry import Option, ScheduleConfig, register

OPTIONS = {
    "particles": Option(int, 4096, "number of particles", minimum=0, maximum=10**12,
                        why=L.WHY_WORK),
    "particle_gpu": Option(int, 1, "GPU that updates the particles (0 = the primary's compute "
                           "queue)", minimum=0, maximum=L.MAX_GPUS - 1, why=L.WHY_ALLOC),
    "policy": Option(str, "new_wait", "'wait': the draw waits for this frame's particles; "
                     "'new_wait': skip the update when the previous one is unfinished",
                     choices=("wait", "new_wait")),
    "draw_after": Option(str, "geometry", "scene pass after which the particles are drawn "
                         "(the geometry pass draws them into the G-buffer)"),
    "vertex_bytes_per_particle": Option(int, 192, "billboard vertex data per particle "
                                        "(6 vertices x 2 float4)", minimum=0, maximum=65536,
                                        why="bytes per particle"),
    "host_copy": Option(bool, True, "the CPU copies the readback buffer into the upload buffer"),
    "update_queue": Option(str, "compute", "queue of the particle GPU that runs the update: "
                           "'compute' (its graphics queue where it has none) or 'graphics'",
                           choices=("compute", "graphics")),
    "one_gpu_path": Option(str, "local", "with particle_gpu = 0: 'local' (the draw reads the "
                           "buffer the update wrote) or 'through_host' (the vertex buffer still "
                           "goes down to the host, through the CPU copy and back up, as from a "
                           "secondary: the particle thesis's one-GPU data path)",
                           choices=("local", "through_host")),
    "cpu_copy": Option(bool, False, "the main thread itself waits for the vertex download and "
                       "copies the readback buffer into the upload buffer (a CPU task at one "
                       "memcpy thread's speed) before it submits the upload; false: the copy "
                       "runs on the memcpy threads (host_copy) or not at all"),
}


@register("particles", "Engine passes on the primary, particle update on a secondary GPU or the "
          "primary's compute queue, 'wait' or 'new wait' policy", OPTIONS)
def build_particles(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    pg, new_wait, n = cfg.opt("particle_gpu"), cfg.opt("policy") == "new_wait", cfg.opt("particles")
    _check(cfg, scene, pg)
    nbytes = n * cfg.opt("vertex_bytes_per_particle")
    queue = (queue_or_graphics(profile, pg, "compute") if cfg.opt("update_queue") == "compute"
             else QueueRef(pg, "graphics"))
    update = PassTask("particle_update", "particle_update", queue,
                      "particle_update", MappingProxyType({"particle": float(n)}),
                      _frame_gate(cfg), skip_if_busy=new_wait)
    chain: list[Task] = [update]
    through = pg == 0 and cfg.opt("one_gpu_path") == "through_host"
    if pg != 0 or through:
        cpu_copy = cfg.opt("cpu_copy")
        chain += cross("particles", profile, pg, 0, nbytes, (Dep(update.name),),
                       Route("transfer", "host", cfg.opt("host_copy") and not cpu_copy),
                       dst_deps=(Dep("particle_render", -2),), skip=new_wait, through_host=through)
        if cpu_copy:
            chain = _copy_on_main_thread(chain, profile, nbytes, new_wait)
    draw_deps = () if new_wait else (Dep(chain[-1].name),)
    tasks = chain + _engine(cfg, scene, n, draw_deps)
    record = {"particles": n, "particle_gpu": pg, "policy": cfg.opt("policy"),
              "vertex_bytes_per_frame": nbytes if pg != 0 or through else 0}
    tasks, resources = _bind(tasks, cfg, scene, n, pg, new_wait)
    return FrameProgram(cfg.name, cfg.gpus, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), rate_tasks=("particle_update",),
                        footprints=_footprints(scene, cfg.gpus, n, pg), resources=resources)


def _frame_gate(cfg: ScheduleConfig) -> tuple[Dep, ...]:
    """What a frame's first GPU work waits for: frame f-fif's present."""
    return (Dep("present", -cfg.frames_in_flight),)


def _copy_on_main_thread(chain: list[Task], profile: HardwareProfile, nbytes: int,
                         new_wait: bool) -> list[Task]:
    """[update, download, upload] -> [update, download, `cpu.particles`, upload]: the main
    thread waits for the download (it wakes on the fence) and copies the readback buffer
    into the upload buffer at one memcpy thread's speed before it submits the upload."""
    update, d2h, h2d = chain
    host = profile.host
    copy = CpuTask("cpu.particles", "cpu_copy", MAIN_THREAD, fixed_ns=host.host_copy_fixed_ns,
                   ns_per_item=1 / host.memcpy_thread_gbps, items=nbytes,
                   deps=(Dep(d2h.name),), skip_if_busy=new_wait)
    return [update, d2h, copy, replace(h2d, deps=(Dep(copy.name),) + h2d.deps[1:])]


def _bind(tasks: list[Task], cfg: ScheduleConfig, scene: Scene, n: int, pg: int,
          new_wait: bool) -> tuple[list[Task], tuple[Resource, ...]]:
    """What every task reads and writes on the Vulkan runner.

    The update keeps the particles in `gpu{pg}.particles.state` and writes copy f % 2 of
    `gpu{pg}.particles.vertices`; from a secondary the vertex buffer crosses to
    `gpu0.particles.vertices` (double-buffered too). The draw adds the billboards to the image
    of the pass it follows. Under 'wait' it reads frame f's vertex buffer; under 'new_wait'
    (`newest_of`) the newest one whose upload (or update, on the primary) finished or was
    queued before the draw on its queue: it lags the newest update by the updates skipped or
    still on their way, never more. Engine passes render full-frame into images of their own
    (`gpu0.pass.X`); present copies the last one to `gpu0.display`."""
    b = Bindings()
    w, h = scene.width, scene.height
    b.image("gpu0.display", 0, w, h)
    state = b.buffer(f"gpu{pg}.particles.state", pg, max(n, 1) * STATE_BYTES)
    vertices = b.buffer(f"gpu{pg}.particles.vertices", pg, max(n, 1) * VERTEX_BYTES, buffers=2)
    shown = b.buffer("gpu0.particles.vertices", 0, max(n, 1) * VERTEX_BYTES, buffers=2)
    why = None
    if pg == 0 and cfg.opt("one_gpu_path") == "through_host":
        why = "the particles' one-GPU path through the host is simulated only"
    elif cfg.opt("vertex_bytes_per_particle") != VERTEX_BYTES:
        why = (f"the runner's particle vertex buffer holds {VERTEX_BYTES} B per particle, not "
               f"schedule.vertex_bytes_per_particle = {cfg.opt('vertex_bytes_per_particle')}")
    crossing = [t for t in tasks if t.name.startswith("particles.")]
    crossed = {t.name: t for t in bind_crossing(crossing, b, vertices, shown,
                                                staging="particles", buffers=2,
                                                params={"unsupported": why} if why else None)}
    writer = crossing[-1].name if crossing else "particle_update"
    draw_into = f"gpu0.pass.{cfg.opt('draw_after')}"
    out: list[Task] = []
    for task in tasks:
        if task.name in crossed:
            out.append(crossed[task.name])
        elif task.name == "particle_update":
            assert isinstance(task, PassTask)
            out.append(replace(task, writes=(vertices, state), params=MappingProxyType(
                {"particles": n, "dt": UPDATE_DT, "seed": 0})))
        elif task.name == "particle_render":
            params = {"particles": n, "clear": False, **({"newest_of": writer} if new_wait else {})}
            assert isinstance(task, PassTask)
            out.append(replace(task, reads=(shown,), writes=(draw_into,),
                               params=MappingProxyType(params)))
        elif isinstance(task, PassTask) and task.step == "render":
            index = next(k for k, s in enumerate(scene.passes) if task.name == f"render.{s.name}")
            spec = scene.passes[index]
            target = pass_image(b, f"gpu0.pass.{spec.name}", 0, scene, spec,
                                buffers=2 if reads_own_output(scene.passes, index) else 1)
            reads = filter_reads(scene.passes, index, lambda s: f"gpu0.pass.{s}")
            out.append(bind_full_frame(task, spec, scene, target, *reads))
        elif task.name == "present":
            assert isinstance(task, PassTask)
            out.append(replace(task, reads=(f"gpu0.pass.{scene.passes[-1].name}",),
                               writes=("gpu0.display",)))
        else:
            out.append(task)
    return out, b.resources()


def _footprints(scene: Scene, gpus: int, particles: int, pg: int) -> tuple[Footprint, ...]:
    """Vertex buffers double-buffered on both GPUs; the calc buffer where updated."""
    vertex, calc = 2 * particles * VERTEX_BYTES, particles * CALC_BYTES
    full = scene.color_bytes + scene.depth_bytes
    primary = Footprint(0, 1.0, full + vertex + (calc if pg == 0 else 0), 0)
    return (primary,) + tuple(Footprint(i, 0.0, vertex + calc if i == pg else 0, 0)
                              for i in range(1, gpus))


def _check(cfg: ScheduleConfig, scene: Scene, pg: int) -> None:
    if pg >= cfg.gpus:
        raise InputError(f"particle_gpu = {pg} but the schedule uses {cfg.gpus} GPU(s)",
                         field="schedule.particle_gpu")
    if cfg.opt("draw_after") not in {p.name for p in scene.passes}:
        raise InputError(f"no scene pass named {cfg.opt('draw_after')!r} "
                         f"(passes: {[p.name for p in scene.passes]})", field="schedule.draw_after")


def _engine(cfg: ScheduleConfig, scene: Scene, n: int, draw_deps: tuple[Dep, ...]) -> list[Task]:
    """The primary's passes in order, the particle draw after `draw_after`, then present."""
    queue = QueueRef(0, "graphics")
    draw = PassSpec("particles", "particle_render", MappingProxyType({"particles": n}))
    at = [p.name for p in scene.passes].index(cfg.opt("draw_after")) + 1
    specs = scene.passes[:at] + (draw,) + scene.passes[at:]
    out: list[Task] = []
    for task in chain_passes(specs, queue, _frame_gate(cfg), scene.pixels,
                             lambda spec: "particle_render" if spec is draw else f"render.{spec.name}",
                             step=lambda spec: "particle_render" if spec is draw else "render",
                             place=scene.whole_frame):
        out.append(replace(task, deps=task.deps + draw_deps) if task.name == "particle_render" else task)
    out.append(present_task(queue, scene.pixels, out[-1].name))
    return out
