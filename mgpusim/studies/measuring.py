"""Measuring a study on Vulkan: the microbenchmark sweeps, then every configuration's runs.

Runs of the configurations are interleaved over the repeats, so that a slow phase of a noisy
machine hits different configurations each round; with `steady_window` the compared run is
the steady window of the repeats (:mod:`mgpusim.measure.steady_window`), written as a measured folder
`runs/<config>/steady`. Every run is kept under `runs/<config>/run<k>`. On lavapipe the speed
probe is timed before the first run of a round and after every run, and each run's probes and
the other processes' load during it go to `runs/run_speed.csv` (:mod:`mgpusim.measure.run_speed`): what the
speed-normalized prediction and its refusal rule read.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from mgpusim.io.writers import write_json, write_measured
from mgpusim.measure import host_load, run_archive, run_speed
from mgpusim.measure import speed_probe as speed
from mgpusim.measure.repeated_runs import with_run_length, write_steady_window
from mgpusim.studies.study_file import Entry, Study
from mgpusim.validation.measured import TRACE_FILES

Progress = Callable[[str], None]


#: A runs folder's record of the study that measured it, which a study checks before using
#: the runs (:mod:`mgpusim.studies.run_sets`).
RECORD = "study.json"


def measure_microbenchmarks(study: Study, out: Path, progress: Progress) -> list[Path]:
    """Run every sweep on one simulated GPU, and every pair sweep alone and on two at once, in
    `rounds` rounds; one table (+ machine record) per pass. Each row has the pass's time, and a
    row of one GPU the process's CPU time while it ran."""
    from mgpusim.measure import microbench as m  # noqa: PLC0415 - Vulkan is needed only to measure
    from mgpusim.real.vulkan.machine import close_gpus, machine_record, make_gpus  # noqa: PLC0415

    mb = study.microbenchmarks
    out.mkdir(parents=True, exist_ok=True)
    threads = study.lavapipe_threads()
    _probe(out, "before the microbenchmarks", threads, progress)
    count = 2 if mb.pairs else 1
    gpus = make_gpus(count, lp_threads=None if threads is None else [threads] * count)
    plan = [(name, sweeps, gpus[:1]) for name, sweeps in mb.sweeps]
    plan += [(name, sweeps, g) for name, sweeps in mb.pairs for g in (gpus[:1], gpus)]
    tables: dict[str, list[pd.DataFrame]] = {name: [] for name in mb.passes()}
    paths = []
    try:
        for r in range(mb.rounds):
            for name, sweeps, on in plan:
                progress(f"measure {name}{' on two GPUs at once' if len(on) > 1 else ''} "
                         f"(round {r + 1}/{mb.rounds})")
                df = m.measure(name, on, {k: list(v) for k, v in sweeps.items()},
                               reps=mb.reps, warmup=mb.warmup)
                tables[name].append(df.assign(repetition=df["repetition"] + r * mb.reps))
        for name in mb.passes():
            path = out / f"{name}.csv"
            m.write_table(pd.concat(tables[name], ignore_index=True), str(path))
            record = machine_record(gpus[:1], {
                "pass": name, "sweeps": _sweep_of(mb.sweeps, name), "pairs": _sweep_of(mb.pairs, name),
                "rounds": mb.rounds, "reps": mb.reps, "warmup": mb.warmup,
                "command": f"mgpusim study measure {study.file}"})
            write_json(record, path.with_name(path.name + ".machine.json"))
            paths.append(path)
    finally:
        close_gpus(gpus)
    _probe(out, "after the microbenchmarks", threads, progress)
    return paths


def _probe(out: Path, point: str, threads: int | None, progress: Progress) -> None:
    """The machine's reference speed now, added to `out`'s probe table (see :mod:`mgpusim.measure.speed_probe`):
    on lavapipe studies (`threads` set), whose GPUs are the host's own shared cores; a real
    GPU's passes at the probe's size last tens of microseconds, too short to tell its speed."""
    if threads is None:
        return
    progress(f"speed probe ({point})")
    speed.append_probe(out / speed.FILE, speed.measure_probe(point, threads))


def _run_prober(threads: int | None) -> Any:
    """The probe kept open over the runs (lavapipe studies; a no-op context on real GPUs)."""
    return speed.Prober(threads) if threads is not None else contextlib.nullcontext()


def _round_probe(out: Path, point: str, prober: speed.Prober | None,
                 progress: Progress) -> list[dict[str, Any]]:
    """The probe at the start of a round of runs, added to `out`'s probe table: the first run's
    probe before it ([] on real GPUs)."""
    if prober is None:
        return []
    progress(f"speed probe ({point})")
    rows = prober.probe(point)
    speed.append_probe(out / speed.FILE, rows)
    return rows


def _sweep_of(sweeps: tuple, name: str) -> dict[str, list[Any]] | list[dict[str, list[Any]]]:
    """Pass `name`'s sweep among `sweeps` as plain lists ({} if it has none; a list of them
    where it has several)."""
    mine = [{k: list(v) for k, v in sweep.items()} for n, sweep in sweeps if n == name]
    return mine[0] if len(mine) == 1 else mine if mine else {}


def measure_runs(study: Study, entries: tuple[Entry, ...], profile: Path, out: Path,
                 progress: Progress, devices: list[int] | None = None) -> dict[str, Path]:
    """Run every entry `repeats` times, interleaved; return each entry's measured folder (its
    steady window, or its single run)."""
    from mgpusim.real.runner.execute import run_experiment  # noqa: PLC0415 - Vulkan is needed only to measure

    rs = study.runs
    threads = study.lavapipe_threads()
    exps = {e.name: with_run_length(e.load(profile), rs.run_seconds, rs.max_frames) for e in entries}
    runs: dict[str, list[tuple[str, Any]]] = {e.name: [] for e in entries}
    out.mkdir(parents=True, exist_ok=True)
    write_json({"study": study.name, "file": str(study.file)}, out / RECORD)
    with _run_prober(threads) as prober:
        before: list[dict[str, Any]] = []
        for rep in range(rs.repeats):
            before = _round_probe(out, f"runs, round {rep + 1} of {rs.repeats}", prober, progress)
            for e in entries:
                progress(f"run {e.name} ({rep + 1}/{rs.repeats})")
                gpus = exps[e.name].schedule.gpus
                load = host_load.sample()
                result = run_experiment(exps[e.name], devices=devices[:gpus] if devices else None,
                                        lp_threads=None if threads is None else [threads] * gpus,
                                        prewarm_frames=rs.prewarm_frames)
                loaded = host_load.load_between(load, host_load.sample())
                folder = out / e.name / f"run{rep}" if rs.repeats > 1 or rs.steady_window else out / e.name
                write_measured(result, folder)
                runs[e.name].append((f"run{rep}", result))
                if prober is not None:  # the probe after this run is the one before the next
                    after = prober.probe(f"after {e.name} run{rep}")
                    run_speed.append(out / run_speed.FILE,
                                     run_speed.record(e.name, f"run{rep}", before, after, loaded))
                    before = after
        if before:
            speed.append_probe(out / speed.FILE, [{**r, "point": "after the runs"} for r in before])
    if rs.steady_window:
        for e in entries:
            write_steady_window(exps[e.name], runs[e.name], out / e.name)
    return {e.name: measured_folder(out, e.name) for e in entries}


def measured_folder(root: Path, name: str) -> Path:
    """Where entry `name`'s compared run lies under `root`: its steady window if it has one,
    else the one run in the folder itself, else the first of its repeated runs."""
    steady = root / name / "steady"
    if run_archive.is_folder(steady):  # a steady window kept: that, whole or not (never a fallback)
        return steady
    for folder in (root / name, root / name / "run0"):
        if any(run_archive.is_file(folder / f) for f in TRACE_FILES):
            return folder
    return root / name
