"""Waits from ready to start (mgpusim.results.waits) and their place in a cross-validation report."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.results.trace import make_trace
from mgpusim.results.waits import LONG_WAIT_NS, compare_waits, ready_waits, wait_stats
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate
from mgpusim.validation.compare import compare
from mgpusim.validation.crossvalidate import format_report

MS = 1_000_000
ROOT = Path(__file__).resolve().parents[1]


def _afr_frames(upload_delay_ns: int):
    """Three AFR frames: frame f renders on GPU f mod 2; frame 1 crosses to GPU 0 (d2h, then
    an h2d that starts `upload_delay_ns` after the d2h ends) and presents there."""
    rows = []
    for f in range(3):
        base = f * 10 * MS
        gpu = f"gpu{f % 2}"
        rows.append((f, gpu, "graphics", "render", "render", base, base + 4 * MS, 0,
                     "-2:present" if f >= 2 else ""))
        if f % 2:
            rows.append((f, gpu, "graphics", "out", "out.d2h", base + 4 * MS, base + 5 * MS, 0, ""))
            start = base + 5 * MS + upload_delay_ns
            rows.append((f, "gpu0", "graphics", "out", "out.h2d", start, start + MS, 0, "0:out.d2h"))
            rows.append((f, "gpu0", "graphics", "present", "present", start + MS, start + 2 * MS, 0, ""))
        else:
            rows.append((f, gpu, "graphics", "present", "present", base + 4 * MS, base + 5 * MS, 0, ""))
    return make_trace(rows)


def _afr_experiment():
    return load_experiment(ROOT / "experiments" / "lavapipe" / "afr.toml",
                           {"schedule.gpus": 2, "schedule.frames": 8, "schedule.warmup_frames": 2})


def test_a_task_waits_on_what_ended_last():
    waits = ready_waits(_afr_frames(3 * MS)).groupby("edge")["wait_ns"].max()
    assert waits["0:out.d2h -> out.h2d"] == 3 * MS  # its input from GPU 1, not GPU 0's queue
    assert waits["queue -> out.d2h"] == 0
    assert waits["queue -> present"] == 0
    # frame 2's render waited for frame 0's present (ended at 5 ms), GPU 0's queue ended later
    assert "queue -> render" in waits.index


def test_first_frame_leaves_the_warm_up_out_but_still_reads_its_ends():
    waits = ready_waits(_afr_frames(0), first_frame=2)
    assert set(waits["edge"]) == {"queue -> render", "queue -> present"}


def test_long_waits_are_counted_and_the_largest_difference_comes_first():
    slow, fast = _afr_frames(3 * MS), _afr_frames(0)
    stats = wait_stats(slow, 0)["0:out.d2h -> out.h2d"]
    assert stats == {"count": 1, "mean_ms": pytest.approx(3.0), "long_share": 1.0}
    assert 3 * MS > LONG_WAIT_NS
    compared = compare_waits(slow, fast, 0)
    first_edge, first = next(iter(compared.items()))
    assert first_edge == "0:out.d2h -> out.h2d"
    assert first["difference_ms"] == pytest.approx(3.0) and first["simulated_ms"] == 0


def test_a_validation_report_names_the_hand_off_the_model_misses():
    exp = _afr_experiment()
    simulated = simulate(exp).trace
    measured = simulated.copy()
    # every upload's start is recorded 0.09 ms later (it is longer than that): a slow hand-off
    late = measured["task"] == "out.h2d"
    assert ((measured.loc[late, "end_ns"] - measured.loc[late, "start_ns"]) > 90_000).all()
    measured.loc[late, "start_ns"] += 90_000
    report = compare(measured, simulated, exp.schedule.warmup_frames)
    edge = next(iter(report["waits"]))
    assert edge.endswith("-> out.h2d")
    assert report["waits"][edge]["difference_ms"] == pytest.approx(0.09)
    assert all(w["difference_ms"] == 0 for e, w in report["waits"].items() if e != edge)
    text = format_report(exp, {**report, "measured_runs": 1})
    assert "waits from ready to start" in text and edge in text


def test_a_report_without_differences_lists_no_waits():
    exp = _afr_experiment()
    trace = simulate(exp).trace
    report = compare(trace, trace, exp.schedule.warmup_frames)
    assert all(w["difference_ms"] == 0 for w in report["waits"].values())
    assert "waits from ready to start" not in format_report(exp, {**report, "measured_runs": 1})


def test_a_host_copy_ends_with_its_last_part():
    rows = [(0, "gpu0", "graphics", "render", "render", 0, MS, 0, ""),
            (0, "host", "memcpy0", "copy", "host_copy", MS, 2 * MS, 0, "0:render"),
            (0, "host", "memcpy1", "copy", "host_copy", MS, 3 * MS, 0, "0:render"),
            (0, "gpu1", "graphics", "in", "in.h2d", 4 * MS, 5 * MS, 0, "0:host_copy")]
    waits = ready_waits(make_trace(rows)).set_index("edge")["wait_ns"]
    assert waits["0:host_copy -> in.h2d"] == MS  # from the second part's end at 3 ms


def test_the_host_split_says_where_a_measured_hand_off_went():
    """out.h2d of frame 1 is ready when GPU 1's d2h ends (5 ms into the frame, 3 ms before it
    starts): its submit thread saw that 1 ms later, called the submit 0.5 ms after that, and
    the device started it 1.5 ms after the call. Hand-offs bound by their queue are left out,
    as is a task without a submissions row."""
    from mgpusim.results.trace import make_submissions
    from mgpusim.results.waits import host_split
    trace = _afr_frames(3 * MS)
    d2h_end = 15 * MS
    rows = [(1, "gpu0", "graphics", "out.h2d", d2h_end + MS, d2h_end + MS + MS // 2,
             d2h_end + 2 * MS),
            (1, "gpu1", "graphics", "render", 9 * MS, 9 * MS, 10 * MS)]
    split = host_split(trace, make_submissions(rows), 0)
    assert list(split) == ["0:out.d2h -> out.h2d"]
    assert split["0:out.d2h -> out.h2d"] == pytest.approx(
        {"input_seen_ms": 1.0, "submit_call_ms": 0.5, "device_start_ms": 1.5, "count": 1})
