"""Reading a saved measured run (from `mgpusim run`, a study, or a committed data folder).

A measured folder holds `trace.parquet` or `trace.csv` in the trace schema and, usually,
`summary.json` with the configuration it was measured with; that configuration must match the
experiment it is compared with, or the comparison would report the difference as model error.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pandas as pd

from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.profile import CalibratedOn, HardwareProfile
from mgpusim.model.tasks import CpuTask, HostCopyTask, QueueRef
from mgpusim.results.trace import SUBMISSION_COLUMNS
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.validation.measured_check import (
    check_physical_gpus,
    check_recorded_config,
    check_trace,
    machine_of,
    read_json_object,
    read_table,
)

TRACE_FILES = ("trace.parquet", "trace.csv")
SUBMISSION_FILES = ("submissions.parquet", "submissions.csv")


def read_measured(folder: Path, exp: Experiment) -> pd.DataFrame:
    """A saved measured trace, checked (columns, whole times, end >= start); its recorded
    configuration (summary.json, required) must match the experiment's in every key both
    record (:mod:`mgpusim.validation.measured_check`)."""
    if not run_archive.is_folder(folder):
        raise InputError("not a folder (expected a measured run from `mgpusim run`)", file=str(folder))
    for name in TRACE_FILES:
        path = folder / name
        if run_archive.is_file(path):
            trace = check_trace(read_table(path, ends_whole=True), str(path))
            break
    else:
        raise InputError("no trace.parquet or trace.csv in the measured folder", file=str(folder))
    summary = folder / "summary.json"
    if not run_archive.is_file(summary):  # without it the run cannot be matched to the experiment
        raise InputError("no summary.json in the measured folder: its recorded configuration is "
                         "what shows the run is of this experiment", file=str(folder))
    config = read_json_object(summary).get("config", {})
    if not isinstance(config, dict):
        raise InputError("expected an object", file=str(summary), field="config")
    check_recorded_config(config, exp, str(summary))
    machine = folder / "machine.json"
    if run_archive.is_file(machine):
        check_physical_gpus(read_json_object(machine), exp, str(machine))
    return trace


def run_machine(folder: Path) -> CalibratedOn | None:
    """The machine a measured run ran on (its `machine.json`), None where the folder has none."""
    machine = folder / "machine.json"
    return machine_of(read_json_object(machine)) if run_archive.is_file(machine) else None


def other_machine(profile: HardwareProfile, ran_on: CalibratedOn | None) -> dict[str, Any] | None:
    """Where the machine that ran a run differs from the one the profile was calibrated on
    (`{"profile": ..., "run": ..., "differs": [field, ...]}`), None where they agree or either
    is unknown. Why: a profile's accuracy holds on its own machine; a comparison of another
    machine's runs with it reads that machine's difference as model error."""
    mine = profile.calibrated_on
    if mine is None or ran_on is None:
        return None
    diff = mine.differences(ran_on)
    if not diff:
        return None
    return {"profile": dataclasses.asdict(mine), "run": dataclasses.asdict(ran_on), "differs": sorted(diff)}


def queues_as_run(trace: pd.DataFrame, program: FrameProgram) -> dict[QueueRef, QueueRef]:
    """Queues of `program` that the measured run replaced by another queue of the same device:
    queue -> the queue its tasks ran on. The runner opens one queue per family, so the tasks of
    a family's second queue run on the first (the run's summary lists them among
    `queue_fallbacks`). A queue some of whose tasks ran on it is kept."""
    ran = trace[["task", "device", "engine"]].drop_duplicates()
    seen: dict[tuple[str, str], set[str]] = {}
    for task, device, engine in ran.itertuples(index=False):
        seen.setdefault((str(task), str(device)), set()).add(str(engine))
    targets: dict[QueueRef, set[str]] = {}
    for tasks in program.templates:
        for t in tasks:
            if not isinstance(t, (HostCopyTask, CpuTask)):
                engines = seen.get((t.name, t.queue.device_name), set())
                targets.setdefault(t.queue, set()).update(engines or {t.queue.engine})
    out = {}
    for queue, engines in targets.items():
        if queue.engine not in engines and len(engines) == 1:
            moved = QueueRef.of(queue.device_name, next(iter(engines)))
            if moved is not None:
                out[queue] = moved
    return out


def read_submissions(folder: Path) -> pd.DataFrame | None:
    """The host side of a measured run's submissions (:data:`mgpusim.results.trace.SUBMISSION_COLUMNS`),
    or None where the folder has none (runs saved before the runner recorded them)."""
    for name in SUBMISSION_FILES:
        path = folder / name
        if run_archive.is_file(path):
            table = read_table(path)
            missing = [c for c in SUBMISSION_COLUMNS if c not in table.columns]
            if missing:
                raise InputError(f"missing columns {missing} (expected {', '.join(SUBMISSION_COLUMNS)})",
                                 file=str(path))
            return table
    return None
