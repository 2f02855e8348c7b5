"""Building an experiment's FrameProgram: the one entry point both executors start from.

Why its own module: the simulator, the Vulkan runner, the memory check and calibration all
need "the program of this experiment", and none of them should import another to get it.
"""
from __future__ import annotations

import json
from dataclasses import replace
from types import MappingProxyType
from typing import Any, Mapping

from mgpusim.model.errors import InputError
from mgpusim.model.tasks import CpuTask, HostCopyTask, QueueRef
from mgpusim.schedules import SCHEDULES, ensure_loaded
from mgpusim.schedules.base import FrameProgram, check_program, with_cpu_frame
from mgpusim.schedules.experiment import Experiment


def build_program(exp: Experiment) -> FrameProgram:
    """The experiment's schedule built on its scene and profile, checked before any run."""
    ensure_loaded()
    try:
        program = SCHEDULES[exp.schedule.name].build(exp.schedule, exp.scene, exp.profile)
    except InputError as exc:  # a builder knows the field (schedule.split_at), not the file
        if exc.file is not None:
            raise
        raise InputError(exc.detail, file=exp.file, field=exc.field) from None
    program = with_cpu_frame(program, exp.schedule.cpu_frame_us, exp.schedule.frames_in_flight)
    check_program(program, exp.profile)
    return with_refresh(program, exp.schedule.refresh_hz)


def with_refresh(program: FrameProgram, refresh_hz: float) -> FrameProgram:
    """The program presenting at a display's refresh (vsync), for any schedule; the Vulkan
    runner has no display to wait for, so its present is marked unsupported there."""
    if not refresh_hz:
        return program
    why = (f"schedule.refresh_hz = {refresh_hz:g}: vsync is simulated only (the runner "
           "presents into an offscreen image)")
    templates = tuple(tuple(replace(t, params=MappingProxyType({**t.params, "unsupported": why}))
                            if t.name == program.present_task and not isinstance(t, HostCopyTask)
                            else t for t in tasks) for tasks in program.templates)
    return replace(program, templates=templates, refresh_hz=refresh_hz)


def on_queues(program: FrameProgram, queues: Mapping[QueueRef, QueueRef]) -> FrameProgram:
    """`program` with the tasks of each queue in `queues` on the queue it maps to, in the same
    submission order. Why: the Vulkan runner opens one queue per family, so the tasks of a
    family's second queue (AFR's and XR's present queue) run on the first, in the program's
    order; a measured run is compared with the program as it ran."""
    if not queues:
        return program
    templates = tuple(tuple(replace(t, queue=queues[t.queue])
                            if not isinstance(t, (HostCopyTask, CpuTask)) and t.queue in queues else t
                            for t in tasks) for tasks in program.templates)
    return replace(program, templates=templates)


def run_config(exp: Experiment, program: FrameProgram) -> dict[str, Any]:
    """What a result records of its configuration, simulated and measured runs alike: the
    experiment, its scene's passes and schedule options, and the program's own record."""
    return {"experiment": exp.name, "file": exp.file, "profile": exp.profile.name,
            "schedule": exp.schedule.name, "gpus": exp.schedule.gpus,
            "width": exp.scene.width, "height": exp.scene.height, **program.record,
            "inputs": recorded_inputs(exp),
            **({"profile_overrides": dict(exp.profile_overrides)} if exp.profile_overrides else {})}


def recorded_inputs(exp: Experiment) -> dict[str, Any]:
    """What a run records of its inputs beyond the basics, so that a measured run can be
    matched to an experiment: the passes with their parameters, the schedule's options and
    frames in flight. JSON-shaped (lists, not tuples), as summary.json stores it."""
    passes = [{"name": p.name, "kind": p.kind, **dict(p.params)} for p in exp.scene.passes]
    schedule = {"frames_in_flight": exp.schedule.frames_in_flight, **dict(exp.schedule.options),
                **{key: getattr(exp.schedule, key) for key in ("refresh_hz", "cpu_frame_us")
                   if getattr(exp.schedule, key)}}
    scene = {key: getattr(exp.scene, key) for key in RECORDED_SCENE_KEYS}
    return json.loads(json.dumps({"passes": passes, "schedule": schedule, "scene": scene}, default=list))


#: The scene's fields beyond its size that a run records (bytes copied and held per frame).
RECORDED_SCENE_KEYS = ("color_bytes_per_pixel", "depth_bytes_per_pixel", "dataset_bytes", "objects")
