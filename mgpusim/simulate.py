"""`simulate(experiment)`: build the schedule, check it, run the engine, tabulate results."""
from __future__ import annotations

from .costs import CostModel
from .errors import TimeBoundError
from .experiment import Experiment
from .memory import check_memory, memory_report
from .program import build_program, run_config
from .results import Result, build_result
from .schedules.base import FrameProgram
from .sim.engine import Engine

__all__ = ["build_program", "run_config", "simulate"]


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
    names = program.rate_tasks
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
