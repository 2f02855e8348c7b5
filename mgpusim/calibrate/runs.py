"""Calibration from measured schedule runs, not only from microbenchmarks.

Two things microbenchmarks cannot give:
- the cost of the passes exactly as the runner records them (its render passes draw into
  the frame's own targets, tiles and geometry shares): fitted from single-GPU runs, where no
  other simulated GPU competes for the cores, row by row with the work terms the schedule
  itself assigns to each task;
- the host's dispatch cost (a thread waking on a fence, then submitting or copying) and how
  much of the cores' time is lost when simulated GPUs oversubscribe them, which only show in
  multi-GPU runs: fitted by a small grid search on the model's frame-time error over the
  multi-GPU calibration runs.
"""
from __future__ import annotations

import copy
from collections import defaultdict
from dataclasses import replace
from typing import Any, Sequence

import numpy as np
import pandas as pd

from ..experiment import Experiment
from ..profile import HardwareProfile, parse_profile
from ..simulate import build_program, simulate
from ..tasks import PassTask
from ..validate import compare
from .fit import Fit, fit_nonnegative

Run = tuple[Experiment, pd.DataFrame]  # an experiment and its measured trace


def fit_passes_from_runs(runs: Sequence[Run]) -> dict[str, Fit]:
    """Per pass kind, fixed_ns + ns_per_<term> fitted on the steady-state rows of 1-GPU runs."""
    rows: dict[str, list[tuple[dict[str, float], float]]] = defaultdict(list)
    for exp, trace in runs:
        if exp.schedule.gpus != 1:
            continue
        program = build_program(exp)
        steady = trace[trace["frame"] >= exp.schedule.warmup_frames]
        for task in program.templates[0]:
            if not isinstance(task, PassTask):
                continue
            durations = steady.loc[steady["task"] == task.name, "end_ns"] - steady.loc[steady["task"] == task.name, "start_ns"]
            rows[task.kind].extend((dict(task.work), float(d)) for d in durations)
    fits = {}
    for kind, samples in rows.items():
        terms = sorted({t for w, _ in samples for t in w})
        X = np.array([[1.0] + [w.get(t, 0.0) for t in terms] for w, _ in samples])
        y = np.array([d for _, d in samples])
        fits[kind] = fit_nonnegative(X, y, ["fixed_ns"] + [f"ns_per_{t}" for t in terms], f"{kind} (runs)")
    return fits


def fit_task_gap(runs: Sequence[Run]) -> int | None:
    """Median idle time between consecutive tasks of one queue in 1-GPU runs (where no other
    device or host thread feeds the queue, so every gap is the queue's own overhead)."""
    gaps: list[np.ndarray] = []
    for exp, trace in runs:
        if exp.schedule.gpus != 1:
            continue
        steady = trace[(trace["frame"] >= exp.schedule.warmup_frames) & (trace["device"] != "host")]
        for _, queue in steady.groupby(["device", "engine"]):
            queue = queue.sort_values("start_ns")
            gaps.append(queue["start_ns"].to_numpy()[1:] - queue["end_ns"].to_numpy()[:-1])
    if not gaps:
        return None
    return int(np.median(np.concatenate(gaps)))


def with_pass_fits(profile_data: dict[str, Any], fits: dict[str, Fit]) -> dict[str, Any]:
    """Profile data with these kinds' coefficients replaced in every GPU entry. A kind fitted
    on runs at one size only keeps its microbenchmark coefficients for the terms the runs could
    not tell apart (they are reported as warnings by the fit)."""
    out = copy.deepcopy(profile_data)
    for gpu in out["gpus"]:
        for kind, fit in fits.items():
            if any("cannot tell" in w for w in fit.warnings):
                continue
            gpu["costs"][kind] = {n: float(f"{v:.6g}") for n, v in zip(fit.names, fit.coef)}
    return out


DISPATCH_GRID_NS = (0, 50_000, 100_000, 200_000, 400_000, 800_000, 1_200_000, 1_600_000)
EFFICIENCY_GRID = (1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7)


def fit_host_effects(profile_data: dict[str, Any], runs: Sequence[Run],
                     dispatch_grid: Sequence[int] = DISPATCH_GRID_NS,
                     efficiency_grid: Sequence[float] = EFFICIENCY_GRID) -> tuple[dict[str, Any], float]:
    """The host dispatch cost and the oversubscribed-core efficiency that minimise the mean
    |frame-time error| of the multi-GPU calibration runs (a grid: two parameters, few runs)."""
    multi = [(exp, trace) for exp, trace in runs if exp.schedule.gpus > 1]
    host = profile_data["host"]
    if not multi:
        return {"dispatch_ns": int(host.get("dispatch_ns", 0)),
                "oversubscribed_efficiency": float(host.get("oversubscribed_efficiency", 1.0))}, float("nan")
    best: tuple[float, int, float] | None = None
    for ns in dispatch_grid:
        for eff in efficiency_grid:
            data = copy.deepcopy(profile_data)
            data["host"].update(dispatch_ns=int(ns), oversubscribed_efficiency=float(eff))
            profile = parse_profile(data, "<calibration>")
            score = float(np.mean([abs(_error(exp, trace, profile)) for exp, trace in multi]))
            if best is None or score < best[0] - 1e-12:
                best = (score, int(ns), float(eff))
    assert best is not None
    return {"dispatch_ns": best[1], "oversubscribed_efficiency": best[2]}, best[0]


def _error(exp: Experiment, trace: pd.DataFrame, profile: HardwareProfile) -> float:
    sim = simulate(replace(exp, profile=profile))
    return compare(trace, sim.trace, exp.schedule.warmup_frames)["frame_time_error"]
