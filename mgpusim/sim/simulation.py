"""`simulate(experiment)`: build the schedule, check it, run the engine, tabulate results."""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Callable, Mapping

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import TimeBoundError
from mgpusim.model.profile import has_cost_stderr, with_cost_band
from mgpusim.model.tasks import QueueRef
from mgpusim.results.summary import Result, build_result, task_rates
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.memory_check import check_memory, memory_report
from mgpusim.schedules.program import build_program, on_queues, run_config
from mgpusim.sim import fastforward
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.engine import Engine
from mgpusim.sim.prepared import cached

__all__ = ["build_program", "run_config", "simulate"]


def simulate(exp: Experiment, record_trace: bool = True, fidelity: str = "full",
             effects: dict[str, bool] | None = None, fast_forward: bool = True,
             band: bool = False, queues: Mapping[QueueRef, QueueRef] | None = None,
             progress: Callable[[int, int], None] | None = None) -> Result:
    """Run `exp` in the model. Same experiment, same result, bit for bit.

    `fidelity`: "full", "queues" or "analytic" (mgpusim.sim.effects); `effects`: effects forced
    on (True) or off (False); `fast_forward`: skip repeats of the model's state (exact).
    `band`: where the profile carries its calibration's standard errors, also simulate every
    pass cost one standard error lower and higher, and report the summary's
    frame_time_ms_lo/hi and latency_ms_lo/hi (the calibration's uncertainty carried through).
    Off by default: it costs two more simulations, which internal callers (calibration
    searches, run lengths, timings) would throw away; `mgpusim simulate` asks for it.
    `queues`: queues whose tasks run on another queue (where a measured run ran them, see
    :func:`mgpusim.schedules.program.on_queues`). `progress(done, total)`: called now and then
    with the frames simulated so far and the frames the run will simulate (a fast-forward
    shortens it), for a command's progress bar."""
    program, chosen, analytic = _prepare(exp, queues, fidelity, effects)
    if "memory_capacity" in chosen:
        check_memory(program, exp)  # overflow is an input error, reported before time 0
    t0 = time.perf_counter()
    raw = _run_model(exp, program, chosen, fidelity, record_trace, fast_forward, progress, analytic)
    model_s = time.perf_counter() - t0
    result = build_result(raw, program.warmup_frames, run_config(exp, program))
    if "memory_capacity" in chosen:
        result.summary["memory"] = memory_report(program, exp)
    result.summary.update(fidelity=fidelity, modelled_effects=sorted(chosen), fast_forward=raw.fast_forward)
    rates = task_rates(program, raw.skipped_frames, result.summary)
    if rates:
        result.summary["task_rates_hz"] = rates
    result.model_wall_s = model_s  # the model's own time (not in the summary: that stays reproducible)
    if band and has_cost_stderr(exp.profile):
        result.summary.update(_band(exp, program, chosen, fidelity))
    return result


def _prepare(exp: Experiment, queues: Mapping[QueueRef, QueueRef] | None, fidelity: str,
             effects: dict[str, bool] | None) -> tuple[FrameProgram, frozenset[str], Callable[[], Any] | None]:
    """The program, the effects chosen and (analytic level) a builder of the recurrence's
    model: kept per experiment object (:mod:`mgpusim.sim.prepared`) when the program is the
    experiment's own (no `queues` moved)."""
    if queues:
        program = on_queues(build_program(exp), queues)
        chosen = choose_effects(program, exp.profile, fidelity, effects)
        return program, chosen, None
    program = cached(exp, "program", lambda: build_program(exp))
    force = tuple(sorted(effects.items())) if effects else ()
    chosen = cached(exp, ("effects", fidelity, force), lambda: choose_effects(program, exp.profile, fidelity, effects))
    if fidelity != "analytic" or program.refresh_hz:  # (the analytic level refuses vsync itself)
        return program, chosen, None
    return program, chosen, lambda: cached(exp, ("analytic", chosen), lambda: _analytic_model(exp, program, chosen))


def _analytic_model(exp: Experiment, program: FrameProgram, chosen: frozenset[str]) -> Any:
    from mgpusim.sim.analytic import Analytic  # noqa: PLC0415 (only this level needs it)
    return Analytic(program, CostModel(exp.profile), chosen)


def _band(exp: Experiment, program: FrameProgram, chosen: frozenset[str], fidelity: str) -> dict[str, float]:
    """Frame time and latency with every pass cost moved one standard error down and up. Why
    both ends are simulated: a schedule's frame time is a maximum over paths, so it need not
    move by the same amount as any one pass."""
    out: dict[str, float] = {}
    for end, sigmas in (("lo", -1.0), ("hi", 1.0)):
        shifted = replace(exp, profile=with_cost_band(exp.profile, sigmas))
        raw = _run_model(shifted, program, chosen, fidelity, False, True)
        summary = build_result(raw, program.warmup_frames, {}).summary
        out[f"frame_time_ms_{end}"] = summary["frame_time_ms"]
        out[f"latency_ms_{end}"] = summary["latency_ms"]
    return out


def _run_model(exp: Experiment, program: FrameProgram, chosen: frozenset[str], fidelity: str,
               record_trace: bool, fast_forward: bool,
               progress: Callable[[int, int], None] | None = None,
               analytic: Callable[[], Any] | None = None):
    """The engine (with its fast-forward) or the analytic recurrence: the RawResult.
    `analytic`: gives the recurrence's model already built (else it is built here)."""
    costs = CostModel(exp.profile)
    try:
        if fidelity == "analytic":
            from mgpusim.sim.analytic import Analytic, model_raw  # noqa: PLC0415 (only this level needs it)
            model = analytic() if analytic is not None else Analytic(program, costs, chosen)
            return model_raw(model, record_trace, progress)
        engine = Engine(program, costs, record_trace=record_trace or fast_forward, effects=chosen)
    except TimeBoundError as exc:  # the profile's rates times the experiment's work
        raise TimeBoundError(f"{exc.detail} (with the work of {exp.file})", file=exc.file,
                             field=exc.field) from None
    return fastforward.run(engine, fast_forward, record_trace, progress)
