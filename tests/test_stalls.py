"""A measured stall (a frame over 3x the mean of the run's other frames) is listed and left out
of the comparison, unless the model's run has such frames too."""
from __future__ import annotations

import pandas as pd
import pytest

from mgpusim.validation.compare import STALL_FACTOR, compare, error_table

MS = 1_000_000


def _trace(periods_ms: list[float], stall_render_ms: float = 4.0) -> pd.DataFrame:
    """One GPU: each frame renders for 4 ms (a frame over 30 ms for `stall_render_ms`), then
    presents for 1 ms; frame f presents periods_ms[f] after frame f-1."""
    rows, present = [], 0
    for f, period in enumerate(periods_ms):
        present += int(period * MS)
        render_ms = stall_render_ms if period > 30 else 4.0
        start = present - int(render_ms * MS) - MS
        rows.append((f, "gpu0", "graphics", "render", "render", start, start + int(render_ms * MS), 0, ""))
        rows.append((f, "gpu0", "graphics", "present", "present", present - MS, present, 0, ""))
    return pd.DataFrame(rows, columns=["frame", "device", "engine", "step", "task", "start_ns",
                                       "end_ns", "bytes", "waits_for"])


def test_a_stalled_frame_is_listed_and_left_out():
    measured = _trace([10.0] * 6 + [55.0] + [10.0] * 5, stall_render_ms=50.0)
    report = compare(measured, _trace([10.0] * 12), warmup_frames=2)
    assert report["stalls"]["frames"] == {"6": pytest.approx(55.0)}
    assert report["measured"]["frame_time_ms"] == pytest.approx(10.0)
    assert report["measured"]["latency_ms"] == pytest.approx(5.0)  # the stalled frame's 51 ms left out
    assert report["frame_time_error"] == pytest.approx(0.0)
    assert error_table([{**report, "config": "c"}])["stalled_frames"].tolist() == [1]


def test_a_frame_just_under_the_factor_is_kept():
    measured = _trace([10.0] * 6 + [STALL_FACTOR * 10.0 - 0.5] + [10.0] * 5)
    report = compare(measured, _trace([10.0] * 12), warmup_frames=2)
    assert report["stalls"]["frames"] == {}
    assert report["measured"]["frame_time_ms"] > 11.0


def test_long_frames_the_model_has_too_belong_to_the_schedule():
    periods = [10.0] * 6 + [45.0] + [10.0] * 5
    assert compare(_trace(periods), _trace([10.0] * 12), warmup_frames=2)["stalls"]["frames"]
    report = compare(_trace(periods), _trace(periods), warmup_frames=2)
    assert report["stalls"]["frames"] == {}
    assert report["frame_time_error"] == pytest.approx(0.0)


def test_afr_presents_in_pairs_are_no_stalls():
    """Two GPUs' frames presented close together, then a long wait: each long period is over
    3x the median period but not over 3x the mean of the others."""
    periods = [1.0, 11.0] * 8
    report = compare(_trace(periods), _trace([6.0] * 16), warmup_frames=1)
    assert report["stalls"]["frames"] == {}
    assert report["measured"]["frame_time_ms"] == pytest.approx(6.0)
