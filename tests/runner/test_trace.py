"""The measured trace has the simulator's schema and names, and honours the schedule."""
from __future__ import annotations

import pandas as pd
import pytest

from mgpusim.model.errors import ScheduleError
from mgpusim.real.runner import run_experiment
from mgpusim.results.trace import SUBMISSION_COLUMNS, TRACE_COLUMNS
from mgpusim.schedules.program import build_program
from mgpusim.sim.simulation import simulate

from .conftest import experiment, lavapipe_profile
from .trace_checks import assert_dependencies_honoured

pytestmark = pytest.mark.vulkan


@pytest.fixture(scope="module")
def sort_first_3():
    exp = experiment("sort_first", 3, width=64, height=256, work=200, frames=6)
    return exp, run_experiment(exp)


def _keys(trace: pd.DataFrame) -> set[tuple]:
    gpu = trace[trace["device"] != "host"]
    return set(map(tuple, gpu[["frame", "device", "engine", "step", "task"]].to_numpy()))


def test_same_rows_and_names_as_the_simulator(sort_first_3):
    exp, measured = sort_first_3
    simulated = simulate(exp)
    assert list(measured.trace.columns) == list(TRACE_COLUMNS)
    assert dict(measured.trace.dtypes.astype(str)) == dict(simulated.trace.dtypes.astype(str))
    assert _keys(measured.trace) == _keys(simulated.trace)
    host = measured.trace[measured.trace["device"] == "host"]
    assert set(host["engine"]) <= {"thread0", "thread1"} and set(host["step"]) == {"host_copy"}
    # host copies: one row per thread part, parts add up to the task's bytes
    program = build_program(exp)
    want = {t.name: t.bytes for t in program.tasks(0) if t.step == "host_copy"}
    got = host.groupby(["frame", "task"])["bytes"].sum()
    assert all(got[(f, name)] == b for f in range(6) for name, b in want.items())
    sim_waits = dict(zip(simulated.trace["task"], simulated.trace["waits_for"]))
    assert all(sim_waits[t] == w for t, w in zip(measured.trace["task"], measured.trace["waits_for"]))


def test_dependencies_and_queue_order_are_honoured(sort_first_3):
    exp, measured = sort_first_3
    tr = measured.trace
    assert_dependencies_honoured(build_program(exp), tr)
    for (_dev, _eng), rows in tr[tr["device"] != "host"].groupby(["device", "engine"]):
        rows = rows.sort_values("start_ns")
        assert (rows["start_ns"].to_numpy()[1:] >= rows["end_ns"].to_numpy()[:-1]).all()
    assert (tr["end_ns"] >= tr["start_ns"]).all() and tr["start_ns"].min() == 0
    s = measured.summary
    assert s["frame_time_ms"] > 0 and s["frames"] == 6 and set(s["step_mean_ms"]) == {
        "render", "d2h", "host_copy", "h2d", "composite", "present"}


def test_every_gpu_task_has_its_host_side(sort_first_3):
    """Each GPU task of the trace has one submissions row on the same clock: its submit thread
    saw its inputs, then called vkQueueSubmit, then got control back (a host copy's row: its
    dispatcher saw its inputs, then queued its parts, before any part began); every input that another
    device or the host produced had ended by then, and the task started after the call (the
    device timestamps are mapped to the host clock to within a few microseconds)."""
    from mgpusim.results.waits import host_split
    exp, measured = sort_first_3
    sub, tr = measured.submissions, measured.trace
    gpu = tr[tr["device"] != "host"]
    assert list(sub.columns) == list(SUBMISSION_COLUMNS)
    copies = sub[sub["device"] == "host"]  # one row per host copy, from its dispatcher
    assert len(sub) - len(copies) == len(gpu)
    parts = tr[tr["device"] == "host"].groupby(["frame", "task"])["start_ns"].min()
    assert len(copies) == len(parts) and (copies["engine"] == "memcpy").all()
    first_part = [parts[(row.frame, row.task)] for row in copies.itertuples()]
    assert (copies["inputs_seen_ns"] <= copies["submit_ns"]).all()
    assert (copies["submit_ns"].to_numpy() <= first_part).all()  # queued, then picked up
    joined = gpu.merge(sub, on=["frame", "device", "engine", "task"], how="inner")
    assert len(joined) == len(gpu)
    assert (joined["inputs_seen_ns"] <= joined["submit_ns"]).all()
    assert (joined["submit_ns"] <= joined["submitted_ns"]).all()
    assert (joined["start_ns"] >= joined["submit_ns"] - 50_000).all()
    host = tr[tr["device"] == "host"].groupby(["frame", "task"])["end_ns"].max()  # all parts
    h2d = joined[joined["step"] == "h2d"]  # h2dK waits on the host for host_copyK of its frame
    copied = [host[(row.frame, row.task.replace("h2d", "host_copy"))] for row in h2d.itertuples()]
    assert len(h2d) == 12 and (h2d["inputs_seen_ns"].to_numpy() >= copied).all()
    split = host_split(tr, sub, 0)  # the hand-offs bound by an input (not by their queue)
    assert split and set(split) <= {"0:d2h1 -> host_copy1", "0:d2h2 -> host_copy2",
                                    "0:host_copy1 -> h2d1", "0:host_copy2 -> h2d2",
                                    "-2:present -> render1", "-2:present -> render2"}
    assert all(p["input_seen_ms"] >= 0 and p["device_start_ms"] > -0.05 for p in split.values())


def test_without_host_copy_there_is_no_step_3():
    result = run_experiment(experiment("sort_last", 2, work=500, frames=3, host_copy=False))
    assert "host_copy" not in set(result.trace["step"])
    assert set(result.trace["step"]) == {"render", "d2h", "h2d", "composite", "present"}


def test_missing_transfer_queue_is_reported():
    exp = experiment("sort_first", 2, frames=3, profile=lavapipe_profile(2, transfer=1))
    result = run_experiment(exp)
    assert any("d2h1: gpu1.transfer -> gpu1.graphics" in f for f in result.summary["queue_fallbacks"])
    assert set(result.trace.loc[result.trace["step"] == "d2h", "engine"]) == {"graphics"}


def test_schedule_without_resources_is_a_clear_error():
    from mgpusim.real.runner.execute import run_program
    from mgpusim.schedules.base import FrameProgram

    program = FrameProgram("x", 1, 2, 0, (tuple(build_program(experiment()).tasks(0)),))
    with pytest.raises(ScheduleError, match="declares no resources"):
        run_program(program, [])
