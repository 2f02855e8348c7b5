"""Dependencies as integer ids: a many-chunk pipeline's trace, its files and its Perfetto
flows cost what its rows cost, not rows times the length of their input lists."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim.io import writers as output
from mgpusim.io.perfetto import chrome_trace
from mgpusim.results.periodic import _SteadyOrder
from mgpusim.results.waits import input_edges, parse_waits_for
from mgpusim.schedules.base import task_device
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.task_inputs import task_inputs
from mgpusim.sim.simulation import build_program, simulate

ROOT = Path(__file__).resolve().parents[1]
PIPE = ROOT / "experiments" / "pipelining_miniengine_pcie3x8.toml"


def _pipe(chunks: int, frames: int = 60):
    return load_experiment(PIPE, {"schedule.chunks": chunks, "schedule.frames": frames})


def _labels_by_rule(program) -> list[str]:
    """The `waits_for` text by its definition: deps on another frame or another device."""
    period, out = len(program.templates), []
    index = [{t.name: t for t in tasks} for tasks in program.templates]
    for phase, tasks in enumerate(program.templates):
        for t in tasks:
            out.append(";".join(f"{d.offset}:{d.task}" for d in t.deps if d.offset or task_device(
                index[(phase + d.offset) % period][d.task]) != task_device(t)))
    return out


@pytest.mark.parametrize("path", ["sort_first_tc1.toml", "afr_temporal_tc1.toml", "particles_machine.toml",
                                  "pipelining_miniengine_pcie3x8.toml"])
def test_labels_built_from_ids_are_the_waits_for_text(path: str):
    program = build_program(load_experiment(ROOT / "experiments" / path))
    assert list(task_inputs(program).labels) == _labels_by_rule(program)


def test_inputs_grow_linearly_with_chunks():
    small, large = (task_inputs(build_program(_pipe(c))) for c in (64, 256))
    assert large.edge_count() <= 4.2 * small.edge_count()
    chars = [sum(map(len, t.labels)) for t in (small, large)]
    assert chars[1] <= 4.5 * chars[0]  # text once per task: linear (it was per row: quadratic)


def test_the_engine_logs_ids_and_the_trace_holds_each_list_once():
    result = simulate(_pipe(32, frames=200))
    assert result.compact
    assert result.repeated.block["waits_for"].dtype == np.int64  # no text per logged row
    trace = result.trace_window(100, 110)
    assert isinstance(trace["waits_for"].dtype, pd.CategoricalDtype)
    assert len(trace["waits_for"].cat.categories) <= len(task_inputs(build_program(_pipe(32))))


@pytest.mark.parametrize("chunks", [1, 16])
def test_steady_periods_tiled_from_one_sorted_period_equal_the_whole_run(chunks: int):
    exp = _pipe(chunks, frames=150)
    on, off = simulate(exp), simulate(exp, fast_forward=False)
    assert _SteadyOrder.of(on.repeated) is not None
    for rows in (500, 10 ** 7):
        pd.testing.assert_frame_equal(pd.concat(list(on.trace_chunks(rows)), ignore_index=True), off.trace)
    for first in (7, 150):
        got = pd.concat(list(on.repeated.chunks(2000, frames=first)), ignore_index=True)
        pd.testing.assert_frame_equal(got, off.trace[off.trace["frame"] < first].reset_index(drop=True))


def test_input_edges_parse_each_distinct_list_once_as_text_does_per_row():
    trace = simulate(_pipe(8, frames=20)).trace
    rows, offset, name = input_edges(trace["waits_for"])
    by_row = [(i, o, t) for i, w in enumerate(trace["waits_for"].astype(str)) for o, t in parse_waits_for(w)]
    assert list(zip(rows.tolist(), offset.tolist(), name.tolist())) == by_row
    text = trace.assign(waits_for=trace["waits_for"].astype(object))  # a measured run's column
    assert [a.tolist() for a in input_edges(text["waits_for"])] == [rows.tolist(), offset.tolist(), name.tolist()]


def test_perfetto_draws_one_arrow_per_listed_input_pair():
    result = simulate(_pipe(8, frames=20))
    trace = result.trace[result.trace["frame"] >= 15]
    doc = chrome_trace(trace, result.links_window(0, 10 ** 18))
    starts = [e for e in doc["traceEvents"] if e["ph"] == "s"]
    long = trace[trace["end_ns"] - trace["start_ns"] >= 2]
    present = set(zip(long["frame"], long["task"].astype(str)))
    pairs = {(f, t, f + o, s) for f, t, w in zip(long["frame"], long["task"].astype(str), long["waits_for"].astype(str))
             for o, s in parse_waits_for(w) if (f + o, s) in present}
    assert len(starts) == len(pairs) > 100


def test_files_hold_the_first_frames_within_the_row_bound(tmp_path: Path, monkeypatch):
    result = simulate(_pipe(16, frames=400))
    per_frame = output.rows_per_frame(result)
    assert per_frame.sum() == len(result.repeated) and (per_frame > 0).all()
    bound = int(per_frame[:50].sum())
    assert output.table_frames(result, bound) == 50 and output.table_frames(result, 0) == 400
    monkeypatch.setattr(output, "PERFETTO_SLICES", int(per_frame[-30:].sum()))
    files = output.write_result(result, tmp_path, trace_rows=bound)
    table = pd.read_parquet(files["trace"])
    assert table["frame"].max() == 49 and len(table) == bound
    assert table["waits_for"].dtype != "category"  # plain text to a reader
    links = pd.read_parquet(files["links"])
    until = result.frames["present_ns"].iloc[49]
    whole = result.links
    assert len(links) == int((whole["start_ns"] <= until).sum())
    doc = json.loads(files["perfetto"].read_text())
    frames = {e["args"]["frame"] for e in doc["traceEvents"] if e["ph"] == "X" and "frame" in e.get("args", {})}
    assert frames == set(range(370, 400))
