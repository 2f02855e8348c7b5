"""Calibration from measured schedule runs, not only from microbenchmarks.

Two things microbenchmarks cannot give:
- the cost of the passes exactly as the runner records them (its render passes draw into
  the frame's own targets, tiles and geometry shares): fitted from single-GPU runs, where no
  other simulated GPU competes for the cores, row by row with the work terms the schedule
  itself assigns to each task;
- the host's dispatch cost (a thread waking on a fence, then submitting or copying), the submit
  time per task, and how much of the cores' time is lost when simulated GPUs oversubscribe
  them, which show mostly in multi-GPU runs: fitted by a small grid search on the model's
  frame-time error over all the calibration runs.
"""
from __future__ import annotations

import copy
import itertools
from collections import defaultdict
from dataclasses import replace
from typing import Any, Iterable, Iterator, Mapping, Sequence, cast

import numpy as np
import pandas as pd

from mgpusim.calibration.fit import Fit, fit_nonnegative
from mgpusim.calibration.profile_out import cost_table
from mgpusim.io.workers import in_workers
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import HardwareProfile, parse_profile
from mgpusim.model.tasks import CopyTask, PassTask, QueueRef, Task
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim.replay import replay
from mgpusim.sim.simulation import simulate
from mgpusim.validation.compare import rel_error, steady_summary
from mgpusim.validation.measured import queues_as_run
from mgpusim.validation.replayed import measured_durations

#: A run's queues that the runner replaced by another, and the queue it used.
Queues = Mapping[QueueRef, QueueRef]

Run = tuple[Experiment, pd.DataFrame]  # an experiment and its measured trace


def tasks_by_name(exp: Experiment) -> dict[str, Task]:
    """The tasks of an experiment's program by the names its traces use."""
    return {t.name: t for tpl in build_program(exp).templates for t in tpl}


def fit_passes_from_runs(runs: Sequence[Run], kinds: Sequence[str] = (), gpus: int | None = None,
                         terms: Sequence[str] | None = None,
                         shapes: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, Fit]:
    """Per pass kind, fixed_ns + ns_per_<term> fitted on the steady-state rows of measured runs,
    row by row with the work terms the schedule itself assigns to each task.

    `kinds`: only these pass kinds (all when empty). `gpus`: only runs with that many GPUs (on a
    CPU-emulated machine 1-GPU runs are the ones where no other simulated GPU competes for the
    cores). `terms`: only these work terms (when every run has the same value of the others, a
    fit could not tell them apart). `shapes`: kinds whose terms keep these relative
    coefficients (the microbenchmarks' fit, made over placements the runs do not vary), with
    only a fixed cost and one scale fitted on the runs."""
    rows: dict[str, list[tuple[dict[str, float], float]]] = defaultdict(list)
    for exp, trace in runs:
        if gpus is not None and exp.schedule.gpus != gpus:
            continue
        program = build_program(exp)
        steady = trace[trace["frame"] >= exp.schedule.warmup_frames]
        duration = steady["end_ns"] - steady["start_ns"]
        for task in program.templates[0]:
            if not isinstance(task, PassTask) or (kinds and task.kind not in kinds):
                continue
            work = {t: (v if terms is None or t in terms else 0.0) for t, v in task.work.items()}
            rows[task.kind].extend((work, float(d)) for d in duration[steady["task"] == task.name])
    fits = {}
    for kind, samples in rows.items():
        if shapes and kind in shapes:
            fits[kind] = _fit_scale(samples, shapes[kind], kind)
            continue
        names = sorted({t for w, _ in samples for t in w} | set(terms or ()))
        X = np.array([[1.0] + [w.get(t, 0.0) for t in names] for w, _ in samples])
        y = np.array([d for _, d in samples])
        fits[kind] = fit_nonnegative(X, y, ["fixed_ns"] + [f"ns_per_{t}" for t in names], f"{kind} (runs)")
    return fits


def _fit_scale(samples: list[tuple[dict[str, float], float]], shape: Mapping[str, float],
               kind: str) -> Fit:
    """fixed_ns + scale x (the shape's cost of each row), as a Fit of the shape's terms."""
    names = sorted(shape)
    X = np.array([[1.0, sum(shape[t] * w.get(t, 0.0) for t in names)] for w, _ in samples])
    y = np.array([d for _, d in samples])
    f = fit_nonnegative(X, y, ["fixed_ns", "scale"], f"{kind} (runs, microbenchmark shape)")
    coef = np.r_[f.coef[0], f.coef[1] * np.array([shape[t] for t in names])]
    err = np.r_[f.stderr[0], f.stderr[1] * np.array([shape[t] for t in names])]
    return Fit(["fixed_ns"] + [f"ns_per_{t}" for t in names], coef, err, f.rel_residuals,
               f.condition, f.warnings)


def fit_alone_scales(runs: Sequence[Run], kinds: Sequence[str],
                     costs: Mapping[str, Mapping[str, float]]) -> dict[str, tuple[float, int]]:
    """For pass kinds that only multi-GPU runs have (a composite): the factor by which their
    instances that ran alone (no pass of another simulated GPU overlapping them) cost more than
    the microbenchmark fit's work terms say, the fixed cost kept: the median over rows of
    (duration - fixed_ns) / (the terms' cost). Returns kind -> (scale, rows).

    Why: on lavapipe a sort-last composite alone in a run costs 1.4-2.1x per pixel and input
    what the microbenchmark measures (median 1.66; its inputs there are never written, its
    target never cleared, its images stay in the caches between repetitions), while the 1-GPU
    runs that refit the other kinds have no composite. Only instances alone on the cores are used, so that the
    sharing the model adds on top is not counted twice."""
    ratios: dict[str, list[float]] = defaultdict(list)
    for task, duration in _alone_instances(runs):
        if not isinstance(task, PassTask) or task.kind not in kinds:
            continue
        cost = costs.get(task.kind, {})
        var = sum(float(cost.get(f"ns_per_{t}", 0.0)) * v for t, v in task.work.items())
        if var > 0:
            ratios[task.kind].append((duration - float(cost.get("fixed_ns", 0.0))) / var)
    # never below 0: instances alone that ran shorter than the fixed cost (small composites on a
    # noisy machine) say the work terms cost nothing more, not that they give time back
    return {k: (max(0.0, float(np.median(r))), len(r)) for k, r in ratios.items()}


def _alone_instances(runs: Sequence[Run]) -> Iterator[tuple[Task, int]]:
    """(task, duration ns) of every GPU task of the multi-GPU runs' steady frames that no pass
    of another simulated GPU overlapped: on CPU-emulated GPUs, what it costs with the cores to
    itself (copies and host threads beside it are small)."""
    for exp, trace in runs:
        if exp.schedule.gpus < 2:
            continue
        tasks = tasks_by_name(exp)
        steady = trace[(trace["frame"] >= exp.schedule.warmup_frames) & (trace["device"] != "host")]
        passes = steady[steady["task"].isin({n for n, t in tasks.items() if isinstance(t, PassTask)})]
        # the passes as arrays: one overlap test per row in numpy, not a DataFrame filter
        p_device = passes["device"].to_numpy()
        p_start, p_end = passes["start_ns"].to_numpy(), passes["end_ns"].to_numpy()
        for name, device, start, end in zip(steady["task"], steady["device"], steady["start_ns"],
                                            steady["end_ns"]):
            task = tasks.get(name)
            if task is None or ((p_device != device) & (p_start < end) & (p_end > start)).any():
                continue
            yield task, end - start


def with_alone_scales(profile_data: dict[str, Any], scales: Mapping[str, tuple[float, int]]) -> dict[str, Any]:
    """Profile data with each kind's work-term coefficients times its scale (fixed_ns kept)."""
    out = copy.deepcopy(profile_data)
    for gpu in out["gpus"]:
        for kind, (scale, _rows) in scales.items():
            table = gpu["costs"].get(kind)
            if table is None:
                continue
            for key in [k for k in table if k.startswith("ns_per_")]:
                table[key] = float(table[key]) * scale
    return out


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
    return max(0, int(np.median(np.concatenate(gaps))))  # overlapping slices must not make it < 0


def fit_host_copy_wake(runs: Sequence[Run]) -> tuple[int, int] | None:
    """Median time from the end of a host copy's last input on a device to the copy's start,
    over the host copies of the runs whose host-copy thread was idle when that input ended (the
    copy before it had finished): the thread's wake latency. Returns (ns, copies) or None when
    no run has such a copy.

    Why measured, not searched: it is one hop the trace shows directly (0.15-0.4 ms on lavapipe,
    where the model had none), and the grid's `dispatch_ns`, shared with every submit thread
    waking on a device, could not take it without making the GPU-to-GPU hand-offs too slow.
    The median is the whole wait, the model's wake latency and its dispatch work together:
    :func:`copy_wake_after_dispatch` splits it once `dispatch_ns` is known."""
    gaps: list[float] = []
    for exp, trace in runs:
        steady = trace[trace["frame"] >= exp.schedule.warmup_frames]
        host = steady[steady["device"] == "host"]
        if host.empty:
            continue
        tasks = tasks_by_name(exp)
        device = steady[steady["device"] != "host"]
        ends = {(int(f), t): int(e) for f, t, e in
                zip(device["frame"], device["task"], device["end_ns"])}
        copies = host.groupby(["frame", "task"], sort=False).agg(
            start=("start_ns", "min"), end=("end_ns", "max")).sort_values("start")
        previous_end = None
        # rows by (frame, task): the index's two levels (pandas-stubs types a label as Hashable)
        for (frame, name), row in cast(Iterable[tuple[tuple[Any, str], pd.Series]], copies.iterrows()):
            found = [ends.get((int(frame) + d.offset, d.task)) for d in tasks[name].deps]
            inputs = [e for e in found if e is not None]
            if inputs:
                last = max(inputs)
                if (previous_end is None or previous_end <= last) and row["start"] >= last:
                    gaps.append(row["start"] - last)
            previous_end = row["end"] if previous_end is None else max(previous_end, row["end"])
    if not gaps:
        return None
    return int(np.median(gaps)), len(gaps)


def copy_wake_after_dispatch(wait_ns: int, dispatch_ns: int) -> int:
    """The host-copy thread's wake latency that, followed by `dispatch_ns` of dispatch work,
    makes the measured wait `wait_ns` (the model spends both before a host copy starts)."""
    return max(0, int(wait_ns) - int(dispatch_ns))


def fit_copy_setup(runs: Sequence[Run], profile_data: dict[str, Any]) -> dict[str, tuple[int, int]]:
    """Per queue family, a copy command's fixed cost as the runs show it: the median over the
    d2h, h2d and d2d copies of multi-GPU runs that no other GPU's pass overlapped of (duration
    - bytes / the path's bandwidth - the path's latency), the bandwidths `profile_data`'s.
    Returns family -> (fixed ns, copies).

    Why: on lavapipe a copy alone in a run took 70-100 us where its microbenchmark (the same
    buffer copied again and again, in the caches) says 52-66 us; the bandwidth is the
    microbenchmarks' (the runs' copies are too small to tell it)."""
    costs = CostModel(parse_profile(copy.deepcopy(profile_data), "<calibration>"))
    fixed: dict[str, list[float]] = defaultdict(list)
    for task, duration in _alone_instances(runs):
        if not isinstance(task, CopyTask) or task.path not in ("d2h", "h2d", "d2d"):
            continue
        dev, family = task.queue.device, task.queue.family
        moved = float(task.bytes / costs.link_bandwidth(dev, task.path))
        own = costs.profile.gpus[dev].copy
        path_latency = (costs.copy_setup_ns(dev, family, task.path)
                        - (own[family].fixed_ns if family in own else 0))
        fixed[family].append(duration - moved - path_latency)
    return {f: (max(0, int(np.median(v))), len(v)) for f, v in fixed.items()}


def with_pass_fits(profile_data: dict[str, Any], fits: dict[str, Fit]) -> dict[str, Any]:
    """Profile data with these kinds' coefficients replaced in every GPU entry. A kind fitted
    on runs at one size only keeps its microbenchmark coefficients for the terms the runs could
    not tell apart (they are reported as warnings by the fit)."""
    out = copy.deepcopy(profile_data)
    for gpu in out["gpus"]:
        for kind, fit in fits.items():
            if any("cannot tell" in w for w in fit.warnings):
                continue
            kept = {k: v for k, v in gpu["costs"].get(kind, {}).items()
                    if k in ("cores", "cpu_overhead_ns", "cores_from_pairs", "term_cores")}
            gpu["costs"][kind] = {**cost_table(fit), **kept}
    return out


#: The host effects searched on multi-GPU runs, and the values tried.
HOST_GRID: dict[str, tuple] = {
    # measured with 2 GPUs: 0.3-0.5 ms from a d2h's end to the host copy; longer values let the
    # search use dispatch as a stand-in for other effects (1.6 ms made small frames 40-50 %
    # too slow in two jobs' refits)
    "dispatch_ns": (0, 100_000, 200_000, 400_000, 800_000),
    "submit_ns": (0, 100_000, 200_000, 400_000, 800_000),
    "oversubscribed_efficiency": (1.0, 0.9, 0.8, 0.7),
}


def fit_host_effects(profile_data: dict[str, Any], runs: Sequence[Run],
                     grid: dict[str, tuple] | None = None,
                     copy_wait_ns: int | None = None,
                     level: str = "prediction") -> tuple[dict[str, Any], float]:
    """The host effects (dispatch cost, per-task submit time, oversubscribed-core efficiency)
    that minimise the mean |frame-time error| over all calibration runs: a grid search, since
    there are three parameters, few runs, and each evaluation is a short simulation. Single-GPU
    runs take part too: a submit thread that is too slow would throttle them. The trials are
    shared among the machine's cores (a study's calibration waits on nothing else); the first
    trial of the lowest error wins, whatever the number of processes. `copy_wait_ns`: the
    measured wait before a host copy (:func:`fit_host_copy_wake`); each trial's
    `host_copy_wake_ns` is what is left of it after the trial's `dispatch_ns`. `level`
    "replay" scores each trial by the replay of every run on its own measured durations
    (:mod:`mgpusim.sim.replay`): the host effects are then fitted on the timeline alone, and a
    pass the cost model gets wrong cannot pull them away from what the hand-offs measure."""
    grid = grid or HOST_GRID
    multi = list(runs)
    host = profile_data["host"]
    if not multi:
        return {k: host.get(k, v[0]) for k, v in grid.items()}, float("nan")
    # the measured side does not change with the trial: summarised once
    measured = [steady_summary(trace, exp.schedule.warmup_frames)["frame_time_ms"]
                for exp, trace in multi]
    trials = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
    if copy_wait_ns is not None:
        for trial in trials:
            trial["host_copy_wake_ns"] = copy_wake_after_dispatch(
                copy_wait_ns, trial.get("dispatch_ns", host.get("dispatch_ns", 0)))
    # each run's schedule as it ran (the runner's one queue per family)
    queues = [queues_as_run(trace, build_program(exp)) for exp, trace in multi]
    replays = [measured_durations(trace) for _, trace in multi] if level == "replay" else None
    scores = _trial_scores(profile_data, [exp for exp, _ in multi], measured, trials, queues, replays)
    best = 0
    for i, score in enumerate(scores):
        if score < scores[best] - 1e-12:
            best = i
    return trials[best], scores[best]


#: What the grid's worker processes read (set before they fork, so nothing is pickled).
_GRID: tuple[dict[str, Any], list[Experiment], list[float], Sequence[Queues], list[Any] | None] | None = None


def _trial_scores(profile_data: dict[str, Any], exps: list[Experiment], measured: list[float],
                  trials: list[dict[str, Any]], queues: Sequence[Queues],
                  replays: list[Any] | None = None) -> list[float]:
    """Mean |frame-time error| of each trial, in trial order, on up to all cores (forked
    workers, at most `MGPUSIM_WORKERS`: :func:`mgpusim.io.workers.in_workers`)."""
    global _GRID
    _GRID = (profile_data, exps, measured, queues, replays)
    try:
        return list(in_workers(_trial_score, [(t,) for t in trials]))
    finally:
        _GRID = None


def _trial_score(trial: dict[str, Any]) -> float:
    assert _GRID is not None
    profile_data, exps, measured, queues, replays = _GRID
    data = copy.deepcopy(profile_data)
    data["host"].update(trial)
    profile = parse_profile(data, "<calibration>")
    if replays is not None:
        return float(np.mean([abs(_replay_error(exp, ms, profile, q, r))
                              for exp, ms, q, r in zip(exps, measured, queues, replays)]))
    return float(np.mean([abs(_error(exp, ms, profile, q)) for exp, ms, q in zip(exps, measured, queues)]))


def _replay_error(exp: Experiment, measured_frame_ms: float, profile: HardwareProfile, queues: Queues,
                  run: tuple[dict[tuple[int, str], int], int]) -> float:
    """Signed frame-time error of the replay of a run (its measured durations) on `profile`."""
    result = replay(replace(exp, profile=profile), run[0], run[1], queues)
    return rel_error(steady_summary(result.trace, exp.schedule.warmup_frames)["frame_time_ms"],
                     measured_frame_ms)


#: Simulated frames after the warm-up in the grid search, for speed: a measured run of
#: thousands of frames needs no simulation as long, though the model's mean frame time is then
#: 0.5-1 % below its value over hundreds of frames (its first frames run into empty queues).
GRID_STEADY_FRAMES = 40


def _error(exp: Experiment, measured_frame_ms: float, profile: HardwareProfile,
           queues: Queues | None = None) -> float:
    """Signed frame-time error of `exp` simulated on `profile` (its tasks on the `queues` the
    run used) against the measured value."""
    sched = exp.schedule
    frames = min(sched.frames, sched.warmup_frames + GRID_STEADY_FRAMES)
    sim = simulate(replace(exp, profile=profile, schedule=replace(sched, frames=frames)), queues=queues)
    return rel_error(steady_summary(sim.trace, sched.warmup_frames)["frame_time_ms"],
                     measured_frame_ms)
