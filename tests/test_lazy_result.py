"""A simulated run's summary comes from arrays at once; its tables are built when read, and
give the summary the tables would give."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim.model.costs import CostModel
from mgpusim.results.summary import build_result, frame_figures, summarize, summarize_arrays
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim import fastforward
from mgpusim.sim.engine import Engine
from mgpusim.sim.simulation import build_program, simulate

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


@pytest.mark.parametrize("name", ["sort_first_tc1", "afr_tc1", "lavapipe/particles"])
def test_frame_figures_are_the_results_own(name):
    """What a band's end reads (frame_figures: the frames alone, no Result built) is what the
    whole Result's summary says; a simulated run's frames need no array of frame numbers."""
    exp = load_experiment(ROOT / "experiments" / f"{name}.toml", {"schedule.frames": 300})
    program = build_program(exp)

    def raw():
        return fastforward.run(Engine(program, CostModel(exp.profile), record_trace=True), True, False)
    whole = build_result(raw(), program.warmup_frames, {}).summary
    alone = frame_figures(raw(), program.warmup_frames)
    assert alone == {k: whole[k] for k in alone}
    start, present = simulate(exp).frame_arrays
    numbered = summarize_arrays(np.arange(len(start)), start, present, program.warmup_frames)
    assert summarize_arrays(None, start, present, program.warmup_frames) == numbered
    assert summarize_arrays(None, start, present, 5, leave_out=[7, 9]) == \
        summarize_arrays(np.arange(len(start)), start, present, 5, leave_out=[7, 9])


def test_a_fast_forwarded_runs_links_come_in_chunks_of_channels(tmp_path):
    """links_chunks joins the channels' pieces into chunks of up to `rows` rows, channel after
    channel: the links file holds the links table (one row group for a short run)."""
    import pyarrow.parquet as pq

    from mgpusim.io.writers import write_links
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 400})
    result = simulate(exp)
    assert result.link_logs is not None and len(result.link_logs) > 1
    small = list(result.links_chunks(rows=7))  # (before the table is built: from the logs)
    write_links(result, tmp_path / "links.parquet")
    whole = result.links.reset_index(drop=True)
    assert all(len(chunk) >= 7 for chunk in small[:-1]) and len(small) > len(result.link_logs)
    assert pd.concat(small, ignore_index=True).equals(whole)
    assert pq.ParquetFile(tmp_path / "links.parquet").num_row_groups == 1
    read = pd.read_parquet(tmp_path / "links.parquet")
    assert read.astype(whole.dtypes.to_dict()).equals(whole)  # (read back, its strings' NA is NaN)
