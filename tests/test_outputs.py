"""`mgpusim simulate` outputs: summary keys, trace schema, PNG, Perfetto tracks and flows."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from mgpusim import simulate
from mgpusim.cli import main
from mgpusim.perfetto import chrome_trace
from mgpusim.trace import TRACE_COLUMNS
from tests.conftest import make_experiment, profile_dict

ROOT = Path(__file__).resolve().parents[1]


def test_simulate_command_writes_all_outputs(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["simulate", str(ROOT / "experiments" / "sort_first_tc1.toml"), "--set", "schedule.gpus=3",
               "--set", "schedule.frames=20", "--out", str(out)])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert {"frame_time_ms", "fps", "latency_ms", "utilization"} <= set(summary)
    assert summary["fps"] > 0 and 0 < summary["utilization"]["gpu0.graphics"] <= 1
    trace = pd.read_parquet(out / "trace.parquet")
    assert list(trace.columns) == list(TRACE_COLUMNS)
    assert set(trace.step) == {"render", "d2h", "host_copy", "h2d", "composite", "present"}
    assert (out / "timeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    perfetto = json.loads((out / "trace.perfetto.json").read_text())
    names = {e["args"]["name"] for e in perfetto["traceEvents"] if e.get("name") == "process_name"}
    assert names == {"gpu0", "gpu1", "gpu2", "host"}
    assert "3 GPU(s)" in capsys.readouterr().out


def test_perfetto_tracks_keep_overlapping_transfers_and_draw_flows():
    # Two secondaries' contributions cross host memory at once: host threads and the
    # host.memory link overlap; nothing may be dropped.
    prof = profile_dict(gpus=3, threads=2, mem_gbps=1.0)
    result = simulate(make_experiment(prof, gpus=3, frames=6, width=64, height=64))
    doc = chrome_trace(result.trace, result.links)
    slices = [e for e in doc["traceEvents"] if e["ph"] == "X"]
    assert len(slices) == len(result.trace) + len(result.links)
    tracks: dict[tuple, list] = {}
    for e in slices:
        tracks.setdefault((e["pid"], e["tid"]), []).append((e["ts"], e["ts"] + e["dur"]))
    for spans in tracks.values():
        spans.sort()
        assert all(b[0] >= a[1] - 1e-9 for a, b in zip(spans, spans[1:])), "overlap on one track"
    thread_names = {e["args"]["name"] for e in doc["traceEvents"] if e.get("name") == "thread_name"}
    assert {"graphics", "transfer", "thread0"} <= thread_names
    starts = [e for e in doc["traceEvents"] if e["ph"] == "s"]
    ends = [e for e in doc["traceEvents"] if e["ph"] == "f"]
    assert starts and len(starts) == len(ends)
    assert any(s["pid"] != f["pid"] for s, f in zip(starts, ends))  # cross-device arrows


def test_effects_report_what_was_simulated():
    single = simulate(make_experiment(gpus=1)).summary["effects"]
    assert single == {"link_model": False, "link_contention": False, "host_copies": False,
                      "host_memory_contention": False}
    multi = simulate(make_experiment(profile_dict(gpus=3, threads=2), gpus=3, width=64, height=64)).summary["effects"]
    assert multi["link_model"] and multi["host_copies"] and multi["host_memory_contention"]


def test_summary_with_one_or_no_steady_frame():
    import numpy as np
    import pytest

    from mgpusim import InputError
    from mgpusim.results import frames_table, summarize
    frames = frames_table(np.array([0, 100, 200]), np.array([150, 260, 370]))
    assert summarize(frames, None, warmup_frames=2)["frame_time_ms"] * 1e6 == 110  # 370 - 260
    assert summarize(frames, None, warmup_frames=1)["frame_time_ms"] * 1e6 == 110
    with pytest.raises(InputError, match="no frame presents after the 3 warm-up frames"):
        summarize(frames, None, warmup_frames=3)
