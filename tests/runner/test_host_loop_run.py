"""The five-step schedule's as-built host loop (the thesis's reference code) run for real: its CPU
tasks on application threads of their own, a barrier per frame, the same picture."""
from __future__ import annotations

import numpy as np
import pytest

from mgpusim.real.runner import run_experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim.simulation import simulate

from .conftest import experiment
from .trace_checks import assert_dependencies_honoured

pytestmark = pytest.mark.vulkan


@pytest.fixture(scope="module")
def as_built():
    exp = experiment("sort_first", 2, frames=5, host_work="as_built")
    return exp, run_experiment(exp)


def test_host_loop_runs_on_its_threads_with_the_simulators_rows(as_built):
    exp, measured = as_built
    t = measured.trace
    loop = t[t["step"] == "host_loop"]
    assert set(zip(loop["device"], loop["engine"])) == {("host", "main"), ("host", "gpu0"), ("host", "gpu1")}
    sim = simulate(exp).trace
    assert set(zip(t["frame"], t["task"])) == set(zip(sim["frame"], sim["task"]))
    assert (loop["end_ns"] >= loop["start_ns"]).all()


def test_each_loop_starts_after_the_last_present(as_built):
    """The barrier: a frame's thread starts come after the previous frame's present, and its
    renders after its thread starts and recordings (the reference code's waits)."""
    _exp, measured = as_built
    t = measured.trace.set_index(["frame", "task"])
    frames = sorted(set(measured.trace["frame"]))
    for f in frames[1:]:
        assert t.loc[(f, "cpu.launch"), "start_ns"] >= t.loc[(f - 1, "present"), "end_ns"]
        for gpu in (0, 1):
            assert t.loc[(f, f"render{gpu}"), "start_ns"] >= t.loc[(f, f"cpu.record{gpu}"), "end_ns"]
        assert t.loc[(f, "cpu.record_d2h1"), "start_ns"] >= t.loc[(f, "render1"), "end_ns"]


def test_the_picture_is_the_overlapped_runs(as_built):
    _exp, measured = as_built
    ref = run_experiment(experiment("sort_first", 2, frames=5))
    assert np.array_equal(measured.image, ref.image)


def test_dependencies_honoured(as_built):
    exp, measured = as_built
    assert_dependencies_honoured(build_program(exp), measured.trace)


def test_every_secondary_s_host_copy_runs_on_threads_of_its_own():
    """bp's hostCopyStep: each secondary's copy is a parallelCopy of its own, its parts on new
    threads, not the runner's memcpy pool: the rows name the copy's own threads, as the
    simulator's do, and the picture is the overlapped loop's."""
    exp = experiment("sort_first", 3, frames=4, host_work="as_built")
    measured = run_experiment(exp)
    copies = measured.trace[measured.trace["step"] == "host_copy"]
    simulated = simulate(exp).trace
    want = set(simulated.loc[simulated["step"] == "host_copy", "engine"])
    assert set(copies["engine"]) == want
    assert want == {f"host_copy{i}.thread{k}" for i in (1, 2)
                    for k in range(len(simulated[(simulated.task == f"host_copy{i}") & (simulated.frame == 0)]))}
    assert_dependencies_honoured(build_program(exp), measured.trace)
    ref = run_experiment(experiment("sort_first", 3, frames=4))
    assert np.array_equal(measured.image, ref.image)
