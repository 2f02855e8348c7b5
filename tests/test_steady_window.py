"""The steady window of noisy measured runs (mgpusim.measure.steady_window)."""
from __future__ import annotations

import pandas as pd
import pytest

from mgpusim.measure import steady_window as sw
from mgpusim.model.errors import InputError
from mgpusim.results.summary import frames_from_trace
from mgpusim.validation.compare import steady_summary

MS = 1_000_000


def run_trace(periods_ms: list[float]) -> pd.DataFrame:
    """A one-GPU trace: frame f renders, then presents at the end of its period."""
    rows, t = [], 0
    for frame, period in enumerate(periods_ms):
        end = t + int(period * MS)
        rows.append((frame, "gpu0", "graphics", "render", "render", t, end - MS // 10, 0, ""))
        rows.append((frame, "gpu0", "graphics", "present", "present", end - MS // 10, end, 0, ""))
        t = end
    return pd.DataFrame(rows, columns=["frame", "device", "engine", "step", "task", "start_ns",
                                       "end_ns", "bytes", "waits_for"])


def test_windows_cover_the_steady_frames_in_order_of_at_least_the_window_length():
    frames = frames_from_trace(run_trace([10.0] * 2 + [10.0] * 40 + [20.0] * 40))
    wins = sw.windows(frames, warmup_frames=2, run=0, window_ms=100)
    assert all(w.last - w.first >= 4 for w in wins)
    assert wins[0].first == 2 and all(a.last == b.first for a, b in zip(wins, wins[1:]))
    assert wins[0].frame_time_ms == pytest.approx(10.0)
    assert wins[-1].frame_time_ms == pytest.approx(20.0)


def test_a_run_shorter_than_a_window_is_one_window():
    frames = frames_from_trace(run_trace([5.0] * 5))
    (only,) = sw.windows(frames, warmup_frames=2, run=3, window_ms=200)
    assert (only.run, only.first, only.last) == (3, 2, 4)


def test_pick_takes_the_quantile_not_the_fastest():
    wins = [sw.Window(0, i, i + 4, t) for i, t in enumerate([9.0, 1.0, 5.0, 7.0, 3.0, 8.0, 6.0,
                                                             4.0, 2.0, 10.0])]
    assert sw.pick(wins, 0.1).frame_time_ms == 1.0
    assert sw.pick(wins, 0.25).frame_time_ms == 3.0
    with pytest.raises(InputError):
        sw.pick([])


def test_window_trace_summarises_to_the_window_frame_time():
    """The fast middle of a slow run: its window's trace, read as any measured run, has the
    window's frame time, and keeps the warm-up frames just before it."""
    trace = run_trace([10.0] * 10 + [6.0] * 10 + [10.0] * 10)
    frames = frames_from_trace(trace)
    fast = sw.pick(sw.windows(frames, 2, 0, window_ms=30), 0.0)
    assert fast.frame_time_ms == pytest.approx(6.0)
    cut = sw.window_trace(trace, fast, warmup_frames=2)
    assert cut["frame"].min() == 0 and cut["frame"].max() == fast.last - fast.first + 2
    assert steady_summary(cut, 2)["frame_time_ms"] == pytest.approx(fast.frame_time_ms)


def test_the_steady_folder_keeps_the_window_of_the_host_side_too(tmp_path):
    """A study keeps only the steady window of its runs: the submissions table is cut to the
    same frames, renumbered as the trace is, so the two still join row by row."""
    from types import SimpleNamespace

    from mgpusim.measure.repeated_runs import write_steady_window
    from mgpusim.results.trace import make_submissions

    def result(periods):
        trace = run_trace(periods)
        subs = make_submissions([(f, d, e, t, s - 50, s - 40, s - 30) for f, d, e, t, s in zip(
            trace["frame"], trace["device"], trace["engine"], trace["task"], trace["start_ns"])])
        return SimpleNamespace(trace=trace, frames=frames_from_trace(trace), submissions=subs,
                               config={}, machine={}, summary={"frame_time_ms": 0.0})

    exp = SimpleNamespace(schedule=SimpleNamespace(warmup_frames=2))
    runs = [("run0", result([10.0] * 30)), ("run1", result([10.0] * 10 + [6.0] * 10 + [10.0] * 10))]
    steady = write_steady_window(exp, runs, tmp_path)
    trace = pd.read_csv(steady / "trace.csv")
    subs = pd.read_csv(steady / "submissions.csv")
    joined = trace.merge(subs, on=["frame", "device", "engine", "task"])
    assert len(joined) == len(trace) == len(subs) and trace["frame"].min() == 0
    assert ((joined["start_ns"] - joined["submit_ns"]) == 40).all()
