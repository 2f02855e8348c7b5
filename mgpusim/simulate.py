"""`simulate(experiment)`: build the schedule, check it, run the engine, tabulate results."""
from __future__ import annotations

from .costs import CostModel
from .errors import InputError, TimeBoundError
from .experiment import Experiment
from .measured_check import recorded_inputs
from .memory import check_memory, memory_report
from .results import Result, build_result
from .schedules import SCHEDULES, ensure_loaded
from .schedules.base import FrameProgram, check_program
from .sim.engine import Engine


def build_program(exp: Experiment) -> FrameProgram:
    ensure_loaded()
    try:
        program = SCHEDULES[exp.schedule.name].build(exp.schedule, exp.scene, exp.profile)
    except InputError as exc:  # a builder knows the field (schedule.split_at), not the file
        if exc.file is not None:
            raise
        raise InputError(exc.detail, file=exp.file, field=exc.field) from None
    check_program(program, exp.profile)
    return program


def run_config(exp: Experiment, program: FrameProgram) -> dict:
    """What a result records of its configuration (simulated and measured runs alike); the
    runner's buffer bindings (notes["resources"]) are left out."""
    return {"experiment": exp.name, "file": exp.file, "profile": exp.profile.name,
            "schedule": exp.schedule.name, "gpus": exp.schedule.gpus,
            "width": exp.scene.width, "height": exp.scene.height,
            **{k: v for k, v in program.notes.items() if k != "resources"},
            "inputs": recorded_inputs(exp)}


def simulate(exp: Experiment, record_trace: bool = True) -> Result:
    """Run `exp` in the model. Same experiment, same result, bit for bit."""
    program = build_program(exp)
    check_memory(program, exp)  # overflow is an input error, reported before time 0
    try:
        engine = Engine(program, CostModel(exp.profile), record_trace=record_trace)
    except TimeBoundError as exc:  # the profile's rates times the experiment's work
        raise TimeBoundError(f"{exc.detail} (with the work of {exp.file})", file=exc.file,
                             field=exc.field) from None
    raw = engine.run()
    result = build_result(raw, program.warmup_frames, run_config(exp, program))
    result.summary["memory"] = memory_report(program, exp)
    _task_rates(program, raw, result)
    return result


def _task_rates(program: FrameProgram, raw, result: Result) -> None:
    """Steady-state completion rate of skippable tasks (e.g. particle updates under "new
    wait"), beside the frame rate: runs in frames after warm-up over the present window."""
    names = program.notes.get("rate_tasks", ())
    if not names:
        return
    lo, hi = result.summary["window_ns"]
    first = program.warmup_frames + 1
    frames = program.frames - first
    rates = {}
    for name in names:
        skipped = sum(1 for f in raw.skipped_frames.get(name, ()) if f >= first)
        rates[name] = (frames - skipped) * 1e9 / (hi - lo) if hi > lo else 0.0
    rates["frames"] = result.summary["fps"]
    result.summary["task_rates_hz"] = rates
