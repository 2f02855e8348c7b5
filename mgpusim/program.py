"""Building an experiment's FrameProgram: the one entry point both executors start from.

Why its own module: the simulator, the Vulkan runner, the memory check and calibration all
need "the program of this experiment", and none of them should import another to get it.
"""
from __future__ import annotations

from typing import Any

from .experiment import Experiment
from .schedules import SCHEDULES, ensure_loaded
from .schedules.base import FrameProgram, check_program


def build_program(exp: Experiment) -> FrameProgram:
    """The experiment's schedule built on its scene and profile, checked before any run."""
    ensure_loaded()
    program = SCHEDULES[exp.schedule.name].build(exp.schedule, exp.scene, exp.profile)
    check_program(program, exp.profile)
    return program


def run_config(exp: Experiment, program: FrameProgram) -> dict[str, Any]:
    """What a result records of its configuration, simulated and measured runs alike: the
    experiment, its scene's passes and schedule options, and the program's own record."""
    return {"experiment": exp.name, "file": exp.file, "profile": exp.profile.name,
            "schedule": exp.schedule.name, "gpus": exp.schedule.gpus,
            "width": exp.scene.width, "height": exp.scene.height, **program.record}
