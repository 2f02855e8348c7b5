"""Alternate-frame rendering (AFR) for N GPUs.

Frame f runs whole on GPU f % N (one template per GPU). A secondary's finished image crosses
to GPU 0, which presents every frame on its present queue (a second graphics queue when it
has one, so presenting never delays GPU 0's own rendering). With a `temporal_pass`, frame f's
pass of that name reads frame f-1's result, which is copied from GPU (f-1) % N first
(F0->F1, F1->F2, ...): the copies that leave idle gaps on both graphics queues in the talk.
Frame pacing is not averaged away: every present is in the frames table and the summary's
frame_time_jitter_ms / min / max come from the individual periods.
"""
from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

from .. import limits as L
from ..errors import InputError
from ..profile import HardwareProfile
from ..scene import Scene
from ..tasks import Dep, PassTask, QueueRef, Task
from .base import (Footprint, FrameProgram, Option, ScheduleConfig, chain_passes, present_task,
                   register)
from .crossing import COPY_OPTIONS, Route, cross

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
}


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
    held = history if temporal and n > 1 else 0
    record = {"temporal_pass": temporal or "", "history_bytes": held,
              "image_bytes": scene.color_bytes,
              "present_queue": str(present_queue(profile, cfg.opt("present_queue")))}
    return FrameProgram(cfg.name, n, cfg.frames, cfg.warmup_frames, templates,
                        record=MappingProxyType(record), footprints=_footprints(scene, n, held))


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
    tasks.append(present_task(present_queue(profile, cfg.opt("present_queue")), scene.pixels, last))
    return tasks


def _renders(gpu: int, scene: Scene, first_deps: tuple[Dep, ...], temporal: str | None,
             history_in: str | None) -> list[PassTask]:
    """The whole frame's passes on one GPU; the temporal pass also waits for the history."""
    out = chain_passes(scene.passes, QueueRef(gpu, "graphics"), first_deps, scene.pixels,
                       lambda spec: f"render.{spec.name}")
    if history_in is None:
        return out
    return [replace(t, deps=t.deps + (Dep(history_in, -1),)) if t.name == temporal else t
            for t in out]
