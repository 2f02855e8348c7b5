"""Measuring on a noisy machine: runs long enough to average the machine's phases, repeated,
and compared over their steady window.

Why: a shared machine delivers its cores in phases (on the 2-core development VM between one
and two cores, in phases of 0.25-2 s), so one short run of a configuration can land in a slow
phase and differ from the next by up to 2x. Interference only ever adds time, so the steady
window of several runs (:mod:`mgpusim.measure.steady_window`) is what the model is compared with, and
the spread of the whole runs says how far the machine itself moved.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from mgpusim.io.writers import write_json, write_measured, write_table
from mgpusim.measure import run_archive
from mgpusim.measure import steady_window as sw
from mgpusim.model.errors import InputError
from mgpusim.schedules.experiment import Experiment
from mgpusim.sim.simulation import simulate


def with_run_length(exp: Experiment, seconds: float, max_frames: int) -> Experiment:
    """`exp` with enough frames that its timed part lasts about `seconds`, as the model on the
    experiment's profile predicts it (at least the experiment's own frames, at most
    `max_frames`)."""
    if seconds <= 0:
        return exp
    sched = exp.schedule
    try:
        frame_ms = float(simulate(exp, record_trace=False).summary["frame_time_ms"])
    except InputError:  # the profile cannot cost a pass yet (a new card, before its calibration)
        return replace(exp, schedule=replace(sched, frames=max(sched.frames, max_frames)))
    frames = max(sched.frames, sched.warmup_frames + math.ceil(seconds * 1e3 / max(frame_ms, 1e-3)))
    return replace(exp, schedule=replace(sched, frames=min(frames, max_frames)))


def write_steady_window(exp: Experiment, runs: list[tuple[str, Any]], out: Path) -> Path:
    """Pick the steady window over `runs` ((name, RunResult) of one configuration), write it as
    a measured folder `out/steady`, and the runs' frame times and the choice to `out/runs.json`."""
    warmup = exp.schedule.warmup_frames
    candidates = [w for i, (_, r) in enumerate(runs) for w in sw.windows(r.frames, warmup, i)]
    window = sw.pick(candidates)
    name, chosen = runs[window.run]
    steady = out / "steady"
    steady.mkdir(parents=True, exist_ok=True)
    write_table(sw.window_trace(chosen.trace, window, warmup), steady / "trace.csv")
    if chosen.submissions is not None and len(chosen.submissions):  # same frames, renumbered
        write_table(sw.window_trace(chosen.submissions, window, warmup), steady / "submissions.csv")
    choice = {"policy": f"window at quantile {sw.QUANTILE} of frame time, windows of at least "
                        f"{sw.WINDOW_MS:g} ms and {sw.MIN_PERIODS} frame periods",
              "run": name, "frames": [window.first, window.last],
              "frames_renumbered_from": window.first - warmup,
              "window_frame_time_ms": window.frame_time_ms, "windows": len(candidates)}
    write_json({"config": chosen.config, "steady_window": choice}, steady / "summary.json")
    write_json(chosen.machine, steady / "machine.json")
    whole = [float(r.summary["frame_time_ms"]) for _, r in runs]
    write_json({"frame_time_ms": whole, **choice}, out / "runs.json")
    return steady


def measure_repeated(exp: Experiment, out: Path, repeats: int, run_seconds: float,
                     max_frames: int = 2000, prewarm_frames: int | None = None) -> Path:
    """Run `exp` `repeats` times (each about `run_seconds` long); keep every run under
    `out/run<k>`; return the measured folder to compare: the steady window of the runs, or the
    one run when there is a single short one."""
    from mgpusim.real.runner.execute import run_experiment  # noqa: PLC0415 - Vulkan is needed only to measure

    exp = with_run_length(exp, run_seconds, max_frames)
    runs = []
    for rep in range(repeats):
        result = run_experiment(exp, prewarm_frames=prewarm_frames)
        write_measured(result, out / f"run{rep}")
        runs.append((f"run{rep}", result))
    if repeats == 1 and run_seconds <= 0:
        return out / "run0"
    return write_steady_window(exp, runs, out)


def run_spread(folder: Path) -> tuple[float, int]:
    """(slowest / fastest - 1) of the whole runs' frame times beside a steady window, and how
    many runs: the machine's own noise (nan, 1 for a single run)."""
    runs_json = folder.parent / "runs.json"
    if folder.name != "steady" or not run_archive.is_file(runs_json):
        return float("nan"), 1
    record = run_archive.read_json(runs_json)
    times = record.get("frame_time_ms") if isinstance(record, dict) else None
    if not isinstance(times, list) or not all(isinstance(t, (int, float)) for t in times):
        raise InputError("expected a list of numbers", file=str(runs_json), field="frame_time_ms")
    spread = float(max(times) / min(times) - 1) if times and min(times) > 0 else float("nan")
    return spread, len(times)
