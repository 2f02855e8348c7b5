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

from .. import limits as L
from ..costs import pass_work
from ..errors import InputError
from ..profile import HardwareProfile
from ..scene import PassSpec, Scene
from ..tasks import Dep, PassTask, QueueRef, Task
from .base import (Footprint, FrameProgram, Option, ScheduleConfig, chain_passes, present_task,
                   queue_or_graphics, register)
from .crossing import Route, cross

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
}


@register("particles", "Engine passes on the primary, particle update on a secondary GPU or the "
          "primary's compute queue, 'wait' or 'new wait' policy", OPTIONS)
def build_particles(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    pg, new_wait, n = cfg.opt("particle_gpu"), cfg.opt("policy") == "new_wait", cfg.opt("particles")
    _check(cfg, scene, pg)
    nbytes = n * cfg.opt("vertex_bytes_per_particle")
    update = PassTask("particle_update", "particle_update", queue_or_graphics(profile, pg, "compute"),
                      "particle_update", MappingProxyType({"particle": float(n)}),
                      (Dep("present", -cfg.frames_in_flight),), skip_if_busy=new_wait)
    chain: list[Task] = [update]
    if pg != 0:
        chain += cross("particles", profile, pg, 0, nbytes, (Dep(update.name),),
                       Route("transfer", "host", cfg.opt("host_copy")),
                       dst_deps=(Dep("particle_render", -2),), skip=new_wait)
    draw_deps = () if new_wait else (Dep(chain[-1].name),)
    tasks = chain + _engine(cfg, scene, n, draw_deps)
    record = {"particles": n, "particle_gpu": pg, "policy": cfg.opt("policy"),
              "vertex_bytes_per_frame": nbytes if pg != 0 else 0}
    return FrameProgram(cfg.name, cfg.gpus, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), rate_tasks=("particle_update",),
                        footprints=_footprints(scene, cfg.gpus, n, pg))


#: Bytes per particle of the vertex buffer (6 vertices x 2 float4) and of the update's calc
#: buffer (2 float4), as the particle pass lays them out.
VERTEX_BYTES, CALC_BYTES = 192, 32


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
    for task in chain_passes(specs, queue, (Dep("present", -cfg.frames_in_flight),), scene.pixels,
                             lambda spec: "particle_render" if spec is draw else f"render.{spec.name}",
                             step=lambda spec: "particle_render" if spec is draw else "render"):
        out.append(replace(task, deps=task.deps + draw_deps) if task.name == "particle_render" else task)
    out.append(present_task(queue, scene.pixels, out[-1].name))
    return out
