"""`simulate(experiment)`: build the schedule, check it, run the engine, tabulate results."""
from __future__ import annotations

import contextlib
import time
from dataclasses import replace
from typing import Any, Callable, Mapping

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError, MgpusimError, TimeBoundError
from mgpusim.model.profile import HardwareProfile, LinkProfile, has_cost_stderr, with_cost_band
from mgpusim.model.profile_reads import outside_shipped, reading, recording, shipped_profiles, unused
from mgpusim.model.tasks import QueueRef
from mgpusim.results.summary import Result, build_result, frame_figures, task_rates
from mgpusim.schedules.afr import with_pace
from mgpusim.schedules.base import FrameProgram, check_program
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.memory_check import check_memory, memory_report
from mgpusim.schedules.program import build_program, on_queues, run_config
from mgpusim.sim import fastforward
from mgpusim.sim.effects import approximations, choose_effects, needed_on_links
from mgpusim.sim.engine import Engine
from mgpusim.sim.prepared import cached

__all__ = ["build_program", "run_config", "simulate"]


def simulate(exp: Experiment, record_trace: bool = True, fidelity: str = "full",
             effects: dict[str, bool] | None = None, fast_forward: bool = True,
             band: bool = False, queues: Mapping[QueueRef, QueueRef] | None = None,
             progress: Callable[[int, int], None] | None = None, check_unused: bool = True) -> Result:
    """Run `exp` in the model. Same experiment, same result, bit for bit.

    `fidelity`: "full", "queues" or "analytic" (mgpusim.sim.effects); `effects`: effects forced
    on (True) or off (False); `fast_forward`: skip repeats of the model's state (exact). A run
    of more than MAX_RECORDED_FRAMES (10^6) frames goes on only once it has fast-forwarded; one
    that has not by the time that is known is an InputError naming `schedule.frames`
    (:mod:`mgpusim.model.limits`).
    `band`: where the profile carries its calibration's standard errors, also simulate every
    pass cost one standard error lower and higher, and report the summary's
    frame_time_ms_lo/hi and latency_ms_lo/hi (the calibration's uncertainty carried through).
    Off by default: it costs two more simulations, which internal callers (calibration
    searches, run lengths, timings) would throw away; `mgpusim simulate` asks for it.
    `queues`: queues whose tasks run on another queue (where a measured run ran them, see
    :func:`mgpusim.schedules.program.on_queues`). `progress(done, total)`: called now and then
    with the frames simulated so far and the frames the run will simulate (a fast-forward
    shortens it), for a command's progress bar. `check_unused`: refuse a ``profile.``
    override the model never reads for this experiment (an InputError naming it); False for a
    caller that sets one value on a family of runs, some of which have no use for it (a case's
    parameters)."""
    exp, reads = _watched(exp, fidelity, effects) if check_unused else (exp, None)
    with reading(reads) if reads is not None else contextlib.nullcontext():
        program, chosen, analytic = _prepare(exp, queues, fidelity, effects)
        if "memory_capacity" in chosen:
            check_memory(program, exp)  # overflow is an input error, reported before time 0
        t0 = time.perf_counter()
        raw = _run_model(exp, program, chosen, fidelity, record_trace, fast_forward, progress, analytic)
        model_s = time.perf_counter() - t0
    if reads is not None:
        _check_used(exp, reads, fidelity)
    result = build_result(raw, program.warmup_frames, run_config(exp, program))
    if "memory_capacity" in chosen:
        result.summary["memory"] = memory_report(program, exp)
    result.summary.update(fidelity=fidelity, modelled_effects=sorted(chosen), fast_forward=raw.fast_forward)
    left = cached(exp, ("approximations", chosen),
                  lambda: approximations(program, exp.profile, chosen, _needed(exp, program)))
    if left or fidelity != "full":  # (full with nothing forced off is the reference: no field)
        result.summary["approximations"] = left
    if exp.profile_overrides:  # a what-if beyond every shipped machine says so
        warnings = outside_shipped(exp.profile_overrides, shipped_profiles())
        if warnings:
            result.summary["warnings"] = warnings
    rates = task_rates(program, raw.skipped_frames, result.summary)
    if rates:
        result.summary["task_rates_hz"] = rates
    result.model_wall_s = model_s  # the model's own time (not in the summary: that stays reproducible)
    del raw  # (the engine's logs, before a band's two runs make theirs)
    if band and has_cost_stderr(exp.profile):
        result.summary.update(_band(exp, program, chosen, fidelity))
    return result


def _watched(exp: Experiment, fidelity: str, effects: dict[str, bool] | None
             ) -> tuple[Experiment, set[str] | None]:
    """With ``profile.`` overrides: the experiment on a copy of its profile that notes what the
    model reads (:mod:`mgpusim.model.profile_reads`), one per level and forced effects (kept
    with the experiment, so that its program and effects stay cached), and the set its runs'
    reads go to. The copy is made once per profile object, whatever experiments share it (a
    sweep's points: one profile per distinct set of profile overrides, a new experiment per
    point); each watched experiment notes its own reads."""
    if not exp.profile_overrides:
        return exp, None
    force = tuple(sorted(effects.items())) if effects else ()
    copy = cached(exp.profile, ("recording",), lambda: recording(exp.profile))
    return cached(exp, ("watched", fidelity, force), lambda: (replace(exp, profile=copy), set()))


def _check_used(exp: Experiment, reads: set[str], fidelity: str) -> None:
    """Every ``profile.`` override is a value the model read for this experiment, or one
    InputError naming the first that is not: its run would report the profile's own figures
    as the what-if's."""
    left = unused(exp.profile_overrides, reads)
    if left:
        raise InputError(f"unused by this experiment: the model reads no such value for its schedule "
                         f"({exp.schedule.name}) and scene at --fidelity {fidelity}, so its results would "
                         "be the profile's own; drop it, or set a value this experiment uses",
                         file=exp.file, field=left[0])


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
    chosen = cached(exp, ("effects", fidelity, force),
                    lambda: choose_effects(program, exp.profile, fidelity, effects, _needed(exp, program)))
    if fidelity != "analytic" or program.refresh_hz:  # (the analytic level refuses vsync itself)
        return program, chosen, None
    return program, chosen, lambda: cached(exp, ("analytic", chosen), lambda: _analytic_model(exp, program, chosen))


def _needed(exp: Experiment, program: FrameProgram) -> frozenset[str]:
    """The effects the experiment's scene needs (every effect's test, run once per experiment:
    the effects of each level, the approximations and the recurrence's notes start from it)."""
    return cached(exp, ("needed",), lambda: choose_effects(program, exp.profile))


def link_free(profile: HardwareProfile) -> HardwareProfile:
    """The profile with every GPU's PCIe link and every peer link's rate and latency zeroed:
    what builds a program (which copies a schedule makes, over which path) and every cost but
    a copy's. Two profiles with the same link-free profile differ only in their copies' times."""
    bare = LinkProfile(pcie_gen=0, lanes=0, latency_ns=0)
    return replace(profile, gpus=tuple(replace(g, link=bare) for g in profile.gpus),
                   peer_links=tuple(replace(p, bandwidth_gbps=0.0, latency_ns=0) for p in profile.peer_links))


def prepare_like(exp: Experiment, source: Experiment, fidelity: str) -> bool:
    """Give `exp` the program of `source` and (analytic level) `source`'s recurrence model
    retimed on `exp`'s links, where the two differ only in their links (:func:`link_free`) and
    choose the same effects; else leave `exp` to be prepared as usual. True where it gave them.
    Two evenly paced AFR experiments may differ in their cadence too (`schedule.pace_us`): `exp`
    gets `source`'s program at its own cadence (:func:`~mgpusim.schedules.afr.with_pace`) and
    the model with the pacer's nodes built again. Why: a search over links and cadences
    (`mgpusim advise`) would build the same program and task graph once per link and cadence.
    The effects are chosen on `exp`'s own profile (and program), and a copy's node (and a
    pacer's) is built again on `exp`'s costs (with its time bound), so a run of `exp` is the
    one it would be on its own. Where building any of it fails here, nothing is given:
    `simulate(exp)` then builds it and reports the error."""
    if exp.profile_overrides or source.profile_overrides:
        return False
    cadence = exp.raw != source.raw
    if (exp.profile is source.profile and not cadence) or (cadence and not _other_cadence(exp, source)):
        return False
    if link_free(exp.profile) != link_free(source.profile):
        return False
    try:
        source_program = program = cached(source, "program", lambda: build_program(source))
        if cadence:
            program = with_pace(source_program, exp.schedule.opt("pace_us"))
            check_program(program, exp.profile)
            needed = choose_effects(program, exp.profile)
        else:
            needed = needed_on_links(program, exp.profile, _needed(source, source_program))
        chosen = choose_effects(program, exp.profile, fidelity, None, needed)
        model = None
        if fidelity == "analytic" and not program.refresh_hz:
            theirs = cached(source, ("effects", fidelity, ()),
                            lambda: choose_effects(source_program, source.profile, fidelity, None,
                                                   _needed(source, source_program)))
            if theirs != chosen:
                return False
            model = cached(source, ("analytic", chosen),
                           lambda: _analytic_model(source, source_program, chosen)
                           ).retimed(CostModel(exp.profile), needed, program if cadence else None)
    except MgpusimError:
        return False
    cached(exp, "program", lambda: program)
    cached(exp, ("needed",), lambda: needed)
    cached(exp, ("effects", fidelity, ()), lambda: chosen)
    cached(exp, ("approximations", chosen), lambda: approximations(program, exp.profile, chosen, needed))
    if model is not None:
        cached(exp, ("analytic", chosen), lambda: model)
    return True


def _other_cadence(exp: Experiment, source: Experiment) -> bool:
    """Whether the two are evenly paced AFR experiments that differ at most in their cadence
    (`schedule.pace_us` of their files as loaded)."""
    if exp.schedule.name != "afr" or source.schedule.name != "afr":
        return False
    if not (exp.schedule.opt("pace_us") and source.schedule.opt("pace_us")):
        return False
    return without_pace(exp.raw) == without_pace(source.raw)


def without_pace(data: Mapping[str, Any]) -> dict[str, Any]:
    """An experiment file's contents (or overrides) without its schedule table's `pace_us`."""
    schedule = data.get("schedule")
    if not isinstance(schedule, Mapping) or "pace_us" not in schedule:
        return dict(data)
    return {**data, "schedule": {k: v for k, v in schedule.items() if k != "pace_us"}}


def _analytic_model(exp: Experiment, program: FrameProgram, chosen: frozenset[str]) -> Any:
    from mgpusim.sim.analytic import Analytic  # noqa: PLC0415 (only this level needs it)
    return Analytic(program, CostModel(exp.profile), chosen, _needed(exp, program))


def _band(exp: Experiment, program: FrameProgram, chosen: frozenset[str], fidelity: str) -> dict[str, float]:
    """Frame time and latency with every pass cost moved one standard error down and up. Why
    both ends are simulated: a schedule's frame time is a maximum over paths, so it need not
    move by the same amount as any one pass."""
    out: dict[str, float] = {}
    for end, sigmas in (("lo", -1.0), ("hi", 1.0)):
        shifted = replace(exp, profile=with_cost_band(exp.profile, sigmas))
        summary = frame_figures(_run_model(shifted, program, chosen, fidelity, False, True), program.warmup_frames)
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
        try:
            if fidelity == "analytic":
                from mgpusim.sim.analytic import Analytic, model_raw  # noqa: PLC0415 (only this level needs it)
                model = analytic() if analytic is not None else Analytic(program, costs, chosen)
                return model_raw(model, record_trace, progress)
            engine = Engine(program, costs, record_trace=record_trace or fast_forward, effects=chosen)
        except TimeBoundError as exc:  # the profile's rates times the experiment's work
            raise _bound_error(exp, program, chosen, fidelity, exc) from None
        return fastforward.run(engine, fast_forward, record_trace, progress)
    except fastforward.Unrepeated as exc:
        raise fastforward.unrepeated_error(program.frames, exc.args[0], exp.file) from None


def _bound_error(exp: Experiment, program: FrameProgram, chosen: frozenset[str], fidelity: str,
                 exc: TimeBoundError) -> TimeBoundError:
    """The time-bound error as the user should read it: naming the ``profile.`` overrides
    without which the task would fit (those the user set, not the coefficient they scaled),
    else the profile field that sets the task's time."""
    culprits = [key for key in exp.profile_overrides if _fits_without(exp, program, chosen, fidelity, key)]
    detail = f"{exc.detail} (with the work of {exp.file})"
    if not culprits:
        return TimeBoundError(detail, file=exc.file, field=exc.field)
    shown = ", ".join(f"{k}={exp.profile_overrides[k]!r}" for k in culprits)
    return TimeBoundError(f"{exc.field}: {detail}; caused by the override {shown}: give a value "
                          "nearer the profile's", field=", ".join(culprits))


def _fits_without(exp: Experiment, program: FrameProgram, chosen: frozenset[str], fidelity: str,
                  key: str) -> bool:
    """Whether every task fits the time bound with the profile overrides but `key` (the model
    built, not run: each task's time is checked as it is built)."""
    from mgpusim.model.profile import load_profile  # noqa: PLC0415
    rest = {k.removeprefix("profile."): v for k, v in exp.profile_overrides.items() if k != key}
    try:
        other = replace(exp, profile=load_profile(exp.profile.source, rest))
        costs = CostModel(other.profile)
        if fidelity == "analytic":
            from mgpusim.sim.analytic import Analytic  # noqa: PLC0415
            Analytic(build_program(other), costs, chosen)
        else:
            Engine(build_program(other), costs, record_trace=False, effects=chosen)
    except InputError:  # TimeBoundError included: still too long, or not loadable without it
        return False
    return True
