"""`mgpusim simulate` outputs: summary keys, trace schema, PNG, Perfetto tracks and flows."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

import mgpusim
from mgpusim import simulate
from mgpusim.cli import main
from mgpusim.io.perfetto import chrome_trace
from mgpusim.results.trace import TRACE_COLUMNS
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
    from mgpusim.results.summary import frames_table, summarize
    frames = frames_table(np.array([0, 100, 200]), np.array([150, 260, 370]))
    assert summarize(frames, None, warmup_frames=2)["frame_time_ms"] * 1e6 == 110  # 370 - 260
    assert summarize(frames, None, warmup_frames=1)["frame_time_ms"] * 1e6 == 110
    with pytest.raises(InputError, match="no frame presents after the 3 warm-up frames"):
        summarize(frames, None, warmup_frames=3)


def _flows_and_slices(doc):
    slices = [e for e in doc["traceEvents"] if e["ph"] == "X"]
    flows: dict[int, dict] = {}
    for e in doc["traceEvents"]:
        if e["ph"] in ("s", "f"):
            flows.setdefault(e["id"], {})[e["ph"]] = e
    return slices, flows


def _enclosing(slices, ev):
    """The slices on the event's track that hold its timestamp strictly inside (in ns)."""
    t = round(ev["ts"] * 1000)
    return [s for s in slices if s["pid"] == ev["pid"] and s["tid"] == ev["tid"]
            and round(s["ts"] * 1000) < t < round((s["ts"] + s["dur"]) * 1000)]


def test_perfetto_flows_bind_inside_exactly_the_intended_slices():
    # Three GPUs over host copies with 2 threads: back-to-back slices on every track, the case
    # where an arrow placed at a slice boundary would bind to the neighbour.
    exp = mgpusim.load_experiment(ROOT / "experiments" / "sort_first_tc1.toml",
                                  {"schedule.gpus": 3, "schedule.frames": 12})
    result = mgpusim.simulate(exp)
    doc = json.loads(json.dumps(chrome_trace(result.trace, result.links)))  # read back as a file would be
    slices, flows = _flows_and_slices(doc)
    assert len(flows) > 20 and all(set(f) == {"s", "f"} for f in flows.values())
    for flow in flows.values():
        assert flow["f"]["bp"] == "e"
        (src,), (dst,) = _enclosing(slices, flow["s"]), _enclosing(slices, flow["f"])
        offset = src["args"]["frame"] - dst["args"]["frame"]
        labels = result.trace[(result.trace["frame"] == dst["args"]["frame"])
                              & (result.trace["task"] == dst["name"])]["waits_for"].iloc[0].split(";")
        assert f"{offset}:{src['name']}" in labels
    # every dependency whose two ends are in the trace has its arrow
    want = {(int(r.frame), r.task, int(r.frame) + int(lab.split(":")[0]), lab.split(":")[1])
            for r in result.trace.itertuples() if r.waits_for for lab in r.waits_for.split(";")
            if int(r.frame) + int(lab.split(":")[0]) >= 0}
    got = set()
    for flow in flows.values():
        (src,), (dst,) = _enclosing(slices, flow["s"]), _enclosing(slices, flow["f"])
        got.add((dst["args"]["frame"], dst["name"], src["args"]["frame"], src["name"]))
    assert got == want


def test_perfetto_counters_and_named_tracks():
    exp = mgpusim.load_experiment(ROOT / "experiments" / "sort_first_tc1.toml",
                                  {"schedule.gpus": 3, "schedule.frames": 12})
    result = mgpusim.simulate(exp)
    doc = chrome_trace(result.trace, result.links, "t")
    events = doc["traceEvents"]
    counters = [e for e in events if e["ph"] == "C"]
    names = {e["name"] for e in counters}
    for channel in set(result.links["channel"]):
        assert f"{channel} bytes/s" in names
    assert {"graphics utilization", "transfer utilization", "link d2h utilization", "memory utilization"} <= names
    # bytes/s integrates back to the bytes each channel moved
    trace = result.trace
    moved = {"gpu1.d2h": trace[(trace.device == "gpu1") & (trace.step == "d2h")]["bytes"].sum(),
             "gpu0.h2d": trace[(trace.device == "gpu0") & (trace.step == "h2d")]["bytes"].sum(),
             "host.memory": trace[trace.device == "host"]["bytes"].sum()}
    for channel, total in moved.items():
        series = sorted((e["ts"], e["args"]["bytes/s"]) for e in counters if e["name"] == f"{channel} bytes/s")
        integral = sum(v * (t1 - t0) * 1e-6 for (t0, v), (t1, _) in zip(series, series[1:]))
        assert integral == pytest.approx(total, rel=1e-6)
        assert series[-1][1] == 0
    busy = [e["args"]["busy"] for e in counters if e["name"].endswith("utilization")]
    assert all(0 <= b <= 1 for b in busy) and max(busy) == 1
    # named processes and threads, every slice on a named track
    procs = {e["pid"]: e["args"]["name"] for e in events if e.get("name") == "process_name"}
    threads = {(e["pid"], e["tid"]): e["args"]["name"] for e in events if e.get("name") == "thread_name"}
    assert set(procs.values()) == {"gpu0", "gpu1", "gpu2", "host"}
    assert all((e["pid"], e["tid"]) in threads for e in events if e["ph"] == "X")
    assert {threads[(e["pid"], e["tid"])] for e in events if e["ph"] == "X" and procs[e["pid"]] == "gpu1"} == {
        "graphics", "transfer", "link d2h"}
    tasks = [e for e in events if e["ph"] == "X" and e["cat"] != "link"]
    assert all(isinstance(e["args"]["frame"], int) and e["args"]["step"] == e["cat"] for e in tasks)
    assert {e["args"]["frame"] for e in tasks} == set(range(12))


def test_simulate_windows_png_and_perfetto(tmp_path):
    out = tmp_path / "w"
    rc = main(["simulate", "sort_first_tc1", "--set", "schedule.frames=40", "--frames", "5:9",
               "--trace-frames", "10", "--out", str(out)])
    assert rc == 0
    doc = json.loads((out / "trace.perfetto.json").read_text())
    frames = {e["args"]["frame"] for e in doc["traceEvents"] if e["ph"] == "X" and e["cat"] != "link"}
    assert frames == set(range(30, 40))
    assert len(pd.read_parquet(out / "trace.parquet")["frame"].unique()) == 40  # the table stays whole
    assert (out / "timeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["simulate", "sort_first_tc1", "--set", "schedule.frames=40", "--trace-frames", "0",
                 "--out", str(tmp_path / "all")]) == 0
    doc = json.loads((tmp_path / "all" / "trace.perfetto.json").read_text())
    assert {e["args"]["frame"] for e in doc["traceEvents"] if e["ph"] == "X" and e["cat"] != "link"} == set(range(40))


@pytest.mark.parametrize("bad", ["5", "9:5", "a:b", "3:3", "50:60"])
def test_bad_frame_window_is_one_error(tmp_path, capsys, bad):
    rc = main(["simulate", "sort_first_tc1", "--set", "schedule.frames=40", f"--frames={bad}",
               "--out", str(tmp_path / "x")])
    assert rc == 2 and "--frames" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_timeline_numbers_frames_and_keeps_the_legend_outside(tmp_path):
    import matplotlib.pyplot as plt

    from mgpusim.io.plot import draw_timeline, step_colours

    exp = mgpusim.load_experiment(ROOT / "experiments" / "particles_machine.toml", {"schedule.frames": 20})
    result = mgpusim.simulate(exp)
    fig, ax = plt.subplots(figsize=(12, 5))
    draw_timeline(ax, result.trace, result.links, "p", frames=range(10, 13))
    fig.canvas.draw()
    texts = {t.get_text() for t in ax.texts}
    assert {"10", "11", "12"} <= texts and not texts - {"9", "10", "11", "12", "13"}
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 >= ax.get_window_extent().x1  # right of the tracks, not over them
    steps = sorted(set(result.trace["step"]) | {"link"})
    assert {t.get_text() for t in ax.get_legend().get_texts()} == set(steps)
    colours = [patch.get_facecolor() for patch in ax.get_legend().get_patches()]
    assert len(set(colours)) == len(steps)
    plt.close(fig)
    many = step_colours([f"s{i}" for i in range(10)] + ["render", "d2h"])
    assert len(set(many.values())) == 12


def test_link_rates_attribute_peer_copies_to_their_link():
    from mgpusim.io.perfetto import link_rates
    from mgpusim.results.trace import make_trace

    # gpu0 has two peer links: each copy goes to the one busy when it ended
    trace = make_trace([(0, "gpu0", "transfer", "p2p", "a", 0, 100, 1000, ""),
                        (0, "gpu0", "transfer", "p2p", "b", 200, 400, 4000, ""),
                        (0, "gpu1", "transfer", "d2h", "c", 0, 50, 500, ""),
                        (0, "host", "thread0", "host_copy", "h", 50, 60, 500, "")])
    links = pd.DataFrame({"channel": ["peer0-1", "peer0-2", "gpu1.d2h", "host.memory"],
                          "start_ns": [10, 250, 0, 50], "end_ns": [100, 400, 50, 60]})
    rates = link_rates(trace, links)
    first = rates.groupby("channel")["bytes_per_s"].first().to_dict()
    assert first == {"peer0-1": 1e10, "peer0-2": 2e10, "gpu1.d2h": 1e10, "host.memory": 5e10}
    assert (rates.groupby("channel")["bytes_per_s"].last() == 0).all()


def test_peer_link_counter_from_a_simulated_run():
    exp = mgpusim.load_experiment(ROOT / "experiments" / "afr_tc1.toml",
                                  {"schedule.frames": 12, "schedule.warmup_frames": 2, "schedule.path": "peer"},
                                  profile=ROOT / "hardware_profiles" / "h200_x2.toml")
    result = mgpusim.simulate(exp)
    assert set(result.links["channel"]) == {"peer1-0"}
    doc = chrome_trace(result.trace, result.links)
    series = sorted((e["ts"], e["args"]["bytes/s"]) for e in doc["traceEvents"]
                    if e["ph"] == "C" and e["name"] == "peer1-0 bytes/s")
    moved = sum(v * (t1 - t0) * 1e-6 for (t0, v), (t1, _) in zip(series, series[1:]))
    assert moved == pytest.approx(result.trace.loc[result.trace["step"] == "p2p", "bytes"].sum(), rel=1e-6)


def test_perfetto_events_follow_the_trace_event_format(tmp_path):
    """What the Chrome/Perfetto JSON importer needs of each event kind, checked on the file."""
    assert main(["simulate", "particles_machine", "--set", "schedule.frames=20", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "trace.perfetto.json").read_text())
    assert doc["displayTimeUnit"] == "ns" and isinstance(doc["traceEvents"], list)
    kinds = set()
    for e in doc["traceEvents"]:
        kinds.add(e["ph"])
        assert isinstance(e["pid"], int) and isinstance(e["name"], str) and e["name"]
        if e["ph"] == "M":
            assert e["name"] in {"process_name", "process_sort_index", "thread_name", "thread_sort_index"}
            assert isinstance(e["tid"], int) and isinstance(e["args"], dict)
            continue
        assert isinstance(e["ts"], (int, float)) and e["ts"] >= 0
        if e["ph"] == "X":
            assert isinstance(e["tid"], int) and e["dur"] >= 0 and isinstance(e["args"], dict)
        elif e["ph"] == "C":
            assert e["args"] and all(isinstance(v, (int, float)) for v in e["args"].values())
        else:
            assert e["ph"] in ("s", "f") and isinstance(e["id"], int) and e["cat"] == "dep"
    assert kinds == {"M", "X", "C", "s", "f"}


def test_perfetto_of_a_window_of_a_one_gpu_run():
    # one GPU: no links; a window keeps the trace's row labels, and two slices overlap on a track
    result = mgpusim.simulate(mgpusim.load_experiment(ROOT / "experiments" / "sort_first_tc1.toml",
                                                      {"schedule.gpus": 1, "schedule.frames": 20}))
    trace = result.trace[result.trace["frame"] >= 15].copy()
    first = trace.index[0]
    trace.loc[first, "end_ns"] = trace.loc[trace.index[1], "end_ns"] + 5  # overlap its successor
    trace.loc[trace.index[1], "engine"] = trace.loc[first, "engine"]
    doc = chrome_trace(trace, None)
    slices = [e for e in doc["traceEvents"] if e["ph"] == "X"]
    assert len(slices) == len(trace) and {e["args"]["frame"] for e in slices} == set(range(15, 20))
    names = {e["args"]["name"] for e in doc["traceEvents"] if e.get("name") == "thread_name"}
    assert f"{trace.loc[first, 'engine']} (2)" in names


def test_comparison_draws_the_simulations_last_frames_beside_a_later_measured_window():
    """A measured steady window (frames 30-33 of a long run) beside a 24-frame simulation: the
    simulated panel shows the simulation's last four frames, not an empty window."""
    import pandas as pd

    from mgpusim.io.plot import comparison_frames
    measured = pd.DataFrame({"frame": list(range(40))})
    simulated = pd.DataFrame({"frame": list(range(24))})
    assert comparison_frames(measured, simulated, [30, 31, 32, 33]) == ([30, 31, 32, 33], [20, 21, 22, 23])
    assert comparison_frames(measured, simulated, [10, 11]) == ([10, 11], [10, 11])


@pytest.mark.parametrize("label", ["a short title", "a title far wider than its figure " * 6])
def test_a_timeline_drawn_once_is_the_tight_picture_savefig_draws(tmp_path, label):
    """save_tight renders once and cuts the picture to the padded tight box: the size savefig's
    tight box gives, every pixel within a sub-pixel shift of its; past the figure, savefig's."""
    import numpy as np
    from matplotlib.figure import Figure
    from PIL import Image

    from mgpusim.io.plot import draw_timeline, save_tight

    result = mgpusim.simulate(mgpusim.load_experiment(ROOT / "experiments" / "particles_machine.toml",
                                                      {"schedule.frames": 12}))
    pictures = []
    for name in ("once", "savefig"):
        fig = Figure(figsize=(9, 4))
        draw_timeline(fig.subplots(), result.trace, result.links, label, frames=range(8, 11))
        path = tmp_path / f"{name}.png"
        save_tight(fig, path, 110) if name == "once" else fig.savefig(path, dpi=110, bbox_inches="tight")
        pictures.append(np.asarray(Image.open(path).convert("RGB")).astype(int))
    once, theirs = pictures
    assert once.shape == theirs.shape
    near = [np.abs(np.roll(once, (dy, dx), axis=(0, 1)) - theirs).max(axis=2) <= 8
            for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    assert np.logical_or.reduce(near)[2:-2, 2:-2].mean() > 0.999
