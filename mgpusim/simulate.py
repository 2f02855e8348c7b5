"""`simulate(experiment)`: build the schedule, check it, run the engine, tabulate results."""
from __future__ import annotations

from .costs import CostModel
from .experiment import Experiment
from .results import Result, build_result
from .schedules import SCHEDULES, ensure_loaded
from .schedules.base import FrameProgram, check_program
from .sim.engine import Engine


def build_program(exp: Experiment) -> FrameProgram:
    ensure_loaded()
    program = SCHEDULES[exp.schedule.name].build(exp.schedule, exp.scene, exp.profile)
    check_program(program, exp.profile)
    return program


def simulate(exp: Experiment, record_trace: bool = True) -> Result:
    """Run `exp` in the model. Same experiment, same result, bit for bit."""
    program = build_program(exp)
    raw = Engine(program, CostModel(exp.profile), record_trace=record_trace).run()
    config = {"experiment": exp.name, "file": exp.file, "profile": exp.profile.name,
              "schedule": exp.schedule.name, "gpus": exp.schedule.gpus,
              "width": exp.scene.width, "height": exp.scene.height, **dict(program.notes)}
    return build_result(raw, program.warmup_frames, config)
