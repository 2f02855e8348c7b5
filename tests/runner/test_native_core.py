"""The native runner core (asked for on lavapipe: runner="native") runs the same program as the
Python executor: the simulator's rows, every dependency honoured, the same picture; what it
cannot run goes to the Python executor, and the summary says which ran and why."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from mgpusim.real.runner import native, run_experiment
from mgpusim.schedules.program import build_program

from . import test_schedule_pictures as pictures
from .conftest import experiment
from .trace_checks import assert_runs_the_simulators_tasks

pytestmark = [pytest.mark.vulkan,
              pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler to build the core")]




@pytest.fixture(scope="module")
def sort_first_pair():
    """Sort-first on 3 GPUs, 12 frames (each recorded slot is used three times), both cores."""
    exp = experiment("sort_first", 3, width=64, height=256, work=200, frames=12)
    return exp, run_experiment(exp, runner="python"), run_experiment(exp, runner="native")


def test_native_core_runs_the_simulators_program(sort_first_pair):
    exp, python, measured = sort_first_pair
    assert python.summary["runner"] == "python" and measured.summary["runner"] == "native"
    assert_runs_the_simulators_tasks(exp, measured.trace)
    tr = measured.trace
    for (_dev, _eng), rows in tr[tr["device"] != "host"].groupby(["device", "engine"]):
        rows = rows.sort_values("start_ns")
        assert (rows["start_ns"].to_numpy()[1:] >= rows["end_ns"].to_numpy()[:-1]).all()
    assert len(tr) == len(python.trace)
    assert np.array_equal(measured.image, python.image)


def test_native_core_records_the_host_side(sort_first_pair):
    """Submission rows as the Python executor writes them: one per GPU task and per host copy,
    inputs seen before the call, a copy's parts queued before the first begins, every part's
    bytes adding up to its copy."""
    exp, python, measured = sort_first_pair
    sub, tr = measured.submissions, measured.trace
    assert list(sub.columns) == list(python.submissions.columns) and len(sub) == len(python.submissions)
    assert (sub["inputs_seen_ns"] <= sub["submit_ns"]).all()
    copies = sub[sub["device"] == "host"]
    parts = tr[tr["device"] == "host"]
    first = parts.groupby(["frame", "task"])["start_ns"].min()
    assert all(row.submit_ns <= first[(row.frame, row.task)] for row in copies.itertuples())
    want = {t.name: t.bytes for t in build_program(exp).tasks(0) if t.step == "host_copy"}
    got = parts.groupby(["frame", "task"])["bytes"].sum()
    assert all(got[(f, name)] == b for f in range(12) for name, b in want.items())
    assert set(parts["engine"]) <= {"thread0", "thread1"}


@pytest.mark.parametrize("schedule, gpus, options", [
    ("afr", 3, {"temporal_pass": "taa", "host_copy": True}),
    ("xr", 4, {"scaling": "strong", "buffers": 3, "frames_in_flight": 2}),
    ("pipelining", 2, {"split_at": 2}),
    ("particles", 2, {"policy": "wait", "particles": pictures.P, "prof": pictures.profile(compute=0)}),
])
def test_native_core_runs_each_schedule(schedule, gpus, options):
    """AFR (a template per GPU), XR strong scaling, pipelining and particles offloaded with
    waits draw what the Python executor draws, in the simulator's order."""
    passes = {"afr": pictures.afr_passes("taa"), "xr": pictures.XR_PASSES["mesh"],
              "pipelining": pictures.pipeline_passes(), "particles": pictures.ENGINE}[schedule]
    exp = pictures.experiment(schedule, gpus, passes, frames=8, **options)
    python = run_experiment(exp, prewarm_frames=0, runner="python")
    measured = run_experiment(exp, prewarm_frames=0, runner="native")
    assert measured.summary["runner"] == "native"
    assert_runs_the_simulators_tasks(exp, measured.trace)
    assert np.array_equal(measured.image, python.image)


def test_what_the_core_cannot_run_goes_to_python(monkeypatch):
    """The particle demo's 'new_wait' decides at submit time whether to skip an update: the
    Python executor runs it, and the summary says so (the core asked for through
    MGPUSIM_RUNNER, as a user would)."""
    exp = pictures.experiment("particles", 2, pictures.ENGINE, frames=4, particles=pictures.P,
                              policy="new_wait")
    program = build_program(exp)
    assert "skippable" in (native.unsupported(program, []) or "")
    monkeypatch.setenv(native.RUNNER_ENV, "native")
    result = run_experiment(exp, prewarm_frames=0)
    assert result.summary["runner"] == "python" and "task_rates_hz" in result.summary
    assert "cannot run this program: it has skippable tasks" in result.summary["runner_note"]


def test_lavapipe_runs_on_the_python_executor_unless_asked(monkeypatch):
    """By default the core runs on real GPUs only: the lavapipe profiles' host effects are the
    Python executor's, and the summary says why it ran."""
    monkeypatch.delenv(native.RUNNER_ENV, raising=False)
    result = run_experiment(experiment("sort_first", 2, frames=3))
    assert result.summary["runner"] == "python"
    assert result.summary["runner_note"].startswith("lavapipe:")
    asked = run_experiment(experiment("sort_first", 2, frames=3), runner="native")
    assert asked.summary["runner"] == "native" and "runner_note" not in asked.summary


def test_runner_cores_benchmark_prints_both_cores(capsys):
    """benchmarks/runner_cores.py: one run on each core, a row each (what they measure is the
    machine's to say, not the test's), and MGPUSIM_RUNNER left as it was."""
    import importlib.util
    import os
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "runner_cores.py"
    spec = importlib.util.spec_from_file_location("runner_cores", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    before = os.environ.get(native.RUNNER_ENV)
    assert module.main(["--reps", "1", "--frames", "10"]) == 0
    assert os.environ.get(native.RUNNER_ENV) == before
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [r[0] for r in rows] == ["python", "native"]
    assert all(float(r[1]) > 0 and int(r[5]) > 0 for r in rows)
