"""A simulated run's summary comes from arrays at once; its tables are built when read, and
give the summary the tables would give."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.results.summary import summarize
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
CASES = [("sort_first_tc1.toml", "full", False), ("sort_first_tc1.toml", "analytic", True),
         ("particles_machine.toml", "full", True), ("afr_temporal_tc1.toml", "queues", True),
         ("lavapipe/pipelining.toml", "full", True)]


@pytest.mark.parametrize("path,fidelity,fast_forward", CASES)
def test_tables_are_built_when_read_and_give_the_same_summary(path, fidelity, fast_forward):
    exp = load_experiment(ROOT / "experiments" / path, {"schedule.frames": 150})
    result = simulate(exp, fidelity=fidelity, fast_forward=fast_forward)
    assert callable(result._trace) and callable(result._frames) and callable(result._links)
    assert "utilization" in result.summary
    frames, trace = result.frames, result.trace  # built now
    assert isinstance(frames, pd.DataFrame) and len(frames) == 150 and len(trace)
    again = summarize(frames, trace, exp.schedule.warmup_frames, result.links)
    for key, value in again.items():
        assert result.summary[key] == value, key


def test_a_run_without_a_trace_still_summarizes():
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml")
    result = simulate(exp, record_trace=False, fast_forward=False)
    assert len(result.trace) == 0 and "utilization" not in result.summary
    assert len(result.frames) == exp.schedule.frames
