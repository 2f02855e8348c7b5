"""Laws every five-step run obeys, over random machines and scenes (Hypothesis)."""
from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from mgpusim import simulate
from mgpusim.schedules.five_step import tile_rows
from tests.conftest import make_experiment, profile_dict

configs = st.fixed_dictionaries({
    "schedule": st.sampled_from(["sort_first", "sort_last"]),
    "gpus": st.integers(1, 4),
    "width": st.integers(1, 64),
    "height": st.integers(1, 48),
    "iterations": st.integers(0, 50),
    "frames_in_flight": st.integers(1, 3),
    "buffers": st.integers(1, 3),
    "host_copy": st.booleans(),
    "threads": st.integers(1, 4),
    "link": st.sampled_from([0.5, 1.0, 7 / 3, 12.0]),
    "latency": st.integers(0, 50),
})


def run(c: dict):
    prof = profile_dict(gpus=4, threads=c["threads"], mem_gbps=c["link"], h2d=c["link"],
                        d2h=c["link"], latency=c["latency"])
    exp = make_experiment(prof, schedule=c["schedule"], gpus=c["gpus"], width=c["width"],
                          height=c["height"], iterations=c["iterations"], frames=8,
                          frames_in_flight=c["frames_in_flight"], buffers=c["buffers"],
                          host_copy=c["host_copy"])
    return simulate(exp)


@settings(max_examples=40, deadline=None)
@given(configs)
def test_queues_never_overlap_and_every_frame_presents_in_order(c):
    result = run(c)
    trace = result.trace
    for _, g in trace.groupby(["device", "engine"]):
        g = g.sort_values("start_ns")
        assert (g.start_ns.to_numpy()[1:] >= g.end_ns.to_numpy()[:-1]).all()
    presents = result.frames.present_ns.to_numpy()
    assert (presents >= 0).all() and (presents[1:] >= presents[:-1]).all()
    assert (result.frames.latency_ns >= 0).all()
    assert (trace.end_ns >= trace.start_ns).all()


@settings(max_examples=40, deadline=None)
@given(configs)
def test_bytes_are_conserved_through_every_copy_step(c):
    trace = run(c).trace
    if c["gpus"] == 1:
        assert set(trace.step) == {"render", "present"}
        return
    if c["schedule"] == "sort_first":
        expected = sum(c["width"] * r * 4 for r in tile_rows(c["height"], c["gpus"])[1:])
    else:
        expected = (c["gpus"] - 1) * c["width"] * c["height"] * 6
    steps = ("d2h", "host_copy", "h2d") if c["host_copy"] else ("d2h", "h2d")
    for step in steps:
        per_frame = trace[trace.step == step].groupby("frame")["bytes"].sum()
        assert (per_frame.reindex(range(8), fill_value=0) == expected).all(), step


@settings(max_examples=15, deadline=None)
@given(configs)
def test_same_input_same_trace(c):
    a, b = run(c), run(c)
    assert a.trace.equals(b.trace) and a.summary == b.summary
