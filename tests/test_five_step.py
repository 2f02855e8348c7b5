"""The five-step sort-first / sort-last schedule in the model."""
from __future__ import annotations

import pandas as pd
import pytest

from mgpusim import simulate
from mgpusim.schedules.five_step import tile_rows
from tests.conftest import make_experiment, profile_dict

STEP_ENGINE = {"render": "graphics", "d2h": "transfer", "h2d": "transfer",
               "composite": "graphics", "present": "graphics"}


def test_tile_rows_equal_with_remainder_last():
    assert tile_rows(768, 3) == [256, 256, 256]
    assert tile_rows(10, 3) == [3, 3, 4]
    assert tile_rows(5, 1) == [5]


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_sort_first_bytes_per_frame(n):
    exp = make_experiment(profile_dict(gpus=4), schedule="sort_first", gpus=n, width=8, height=10, frames=4)
    trace = simulate(exp).trace
    rows = tile_rows(10, n)
    expected = sum(8 * r * 4 for r in rows[1:])
    for step in ("d2h", "host_copy", "h2d"):
        per_frame = trace[trace.step == step].groupby("frame")["bytes"].sum()
        if n == 1:
            assert per_frame.empty
        else:
            assert (per_frame == expected).all() and len(per_frame) == 4


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_sort_last_bytes_per_frame(n):
    exp = make_experiment(profile_dict(gpus=4), schedule="sort_last", gpus=n, width=8, height=10, frames=4)
    trace = simulate(exp).trace
    per_frame = trace[trace.step == "d2h"].groupby("frame")["bytes"].sum()
    assert per_frame.reindex(range(4), fill_value=0).tolist() == [(n - 1) * 8 * 10 * (4 + 2)] * 4


def test_single_gpu_baseline_only_renders_and_presents():
    trace = simulate(make_experiment(schedule="sort_first", gpus=1)).trace
    assert set(trace.step) == {"render", "present"}
    assert set(trace.device) == {"gpu0"}


def _check_order_and_engines(trace: pd.DataFrame, n: int) -> None:
    for (dev, eng), g in trace.groupby(["device", "engine"]):
        g = g.sort_values("start_ns")
        assert (g.start_ns.to_numpy()[1:] >= g.end_ns.to_numpy()[:-1]).all(), f"{dev}.{eng} overlaps"
    for _, row in trace[trace.device != "host"].iterrows():
        assert row.engine == STEP_ENGINE[row.step], row.to_dict()
    assert (trace[trace.step == "h2d"].device == "gpu0").all()
    assert trace[trace.step == "host_copy"].engine.str.startswith("thread").all()
    for frame, f in trace.groupby("frame"):
        end = f.groupby("task")["end_ns"].max()
        start = f.groupby("task")["start_ns"].min()
        for i in range(1, n):
            assert start[f"d2h{i}"] >= end[f"render{i}"]
            assert start[f"host_copy{i}"] >= end[f"d2h{i}"]
            assert start[f"h2d{i}"] >= end[f"host_copy{i}"]
            assert start["composite"] >= end[f"h2d{i}"]
        assert start["present"] >= end["composite" if n > 1 else "render0"]


@pytest.mark.parametrize("schedule", ["sort_first", "sort_last"])
@pytest.mark.parametrize("n", [2, 3, 4])
def test_dependency_order_engines_and_no_queue_overlap(schedule, n):
    prof = profile_dict(gpus=4, threads=3, mem_gbps=2.0)
    trace = simulate(make_experiment(prof, schedule=schedule, gpus=n, frames=8, width=64, height=64)).trace
    _check_order_and_engines(trace, n)


def test_no_transfer_queue_puts_copies_on_graphics():
    trace = simulate(make_experiment(profile_dict(transfer=0), gpus=2)).trace
    assert set(trace[trace.step.isin(["d2h", "h2d"])].engine) == {"graphics"}


def test_shared_host_memory_variant_skips_host_copy():
    with_copy = simulate(make_experiment(gpus=2, frames=12))
    shared = simulate(make_experiment(gpus=2, frames=12, host_copy=False))
    assert "host_copy" not in set(shared.trace.step)
    assert shared.summary["latency_ms"] < with_copy.summary["latency_ms"]


def test_pipelined_period_matches_hand_calculation():
    """8x4 sort-first, 2 GPUs, 1 B/ns everywhere, 20 iterations: tiles of 16 px.
    render 320 ns, d2h / host copy / h2d 64 ns each (64 B), composite 16 ns, present 10 ns.
    A frame's chain is L = 320 + 3 * 64 + 16 + 10 = 538 ns; the primary's graphics queue needs
    B = 320 + 16 + 10 = 346 ns per frame. With F frames in flight the period is max(B, L / F):
    346 ns pipelined (F = 2), 538 ns with one frame in flight."""
    piped = simulate(make_experiment(gpus=2, frames=20, iterations=20))
    serial = simulate(make_experiment(gpus=2, frames=20, iterations=20, frames_in_flight=1))
    assert piped.summary["frame_time_ms"] * 1e6 == pytest.approx(346, abs=1e-9)
    assert piped.summary["frame_time_jitter_ms"] == 0
    assert serial.summary["frame_time_ms"] * 1e6 == pytest.approx(538, abs=1e-9)
    assert serial.summary["latency_ms"] * 1e6 == pytest.approx(538, abs=1e-9)
    first = piped.trace[piped.trace.frame == 0].set_index("task")
    assert first.loc["render1", "end_ns"] == 320
    assert first.loc["d2h1", "end_ns"] == 384
    assert first.loc["h2d1", "end_ns"] == 512
    assert first.loc["present", "end_ns"] == 538


def test_latency_chain_limits_period_with_two_frames_in_flight():
    """With 10 iterations, L = 378 and B = 186 < L / 2: presents alternate 186 / 192 ns and
    the mean period is L / 2 = 189 ns (measured over an even number of periods)."""
    r = simulate(make_experiment(gpus=2, frames=21, iterations=10))  # 18 steady periods
    periods = r.frames.present_ns.diff().iloc[3:].astype(int).tolist()
    assert set(periods) == {186, 192}
    assert r.summary["frame_time_ms"] * 1e6 == pytest.approx(189, abs=1e-9)


def test_same_input_same_trace():
    a = simulate(make_experiment(profile_dict(threads=4, mem_gbps=3.0), gpus=2, frames=30, width=700, height=500))
    b = simulate(make_experiment(profile_dict(threads=4, mem_gbps=3.0), gpus=2, frames=30, width=700, height=500))
    pd.testing.assert_frame_equal(a.trace, b.trace)
    assert a.summary == b.summary


def test_task_gap_idles_the_queue_between_tasks():
    prof = profile_dict()
    prof["gpus"][0]["task_gap_ns"] = 5
    trace = simulate(make_experiment(prof, gpus=1, frames=3, iterations=20)).trace.set_index(["frame", "task"])
    # One GPU renders all 32 px x 20 iterations = 640 ns, present 10 ns; each after a 5 ns gap.
    assert trace.loc[(0, "render0"), "start_ns"] == 5
    assert trace.loc[(0, "present"), "start_ns"] == 5 + 640 + 5
    assert trace.loc[(1, "render0"), "start_ns"] == 650 + 10 + 5


def test_pipelining_modes_exact_timeline():
    """The hand-computed 8x4 frame above (render 320, d2h / host copy / h2d 64 each, composite
    16, present 10). 'secondary_wait': GPU 1 renders frame f+1 only after its download of frame
    f ended (384), so its queue carries 320 + 64 per frame: render1 384-704, d2h 704-768, host
    copy -832, h2d -896; render0(1) 538-858 after present(0); composite 896-912, present 922;
    then one present every 384 ns. 'lockstep': no frame starts before the last present: 538 ns.
    'full' is the default (346 ns, above)."""
    wait = simulate(make_experiment(gpus=2, frames=6, iterations=20, pipelining="secondary_wait"))
    assert wait.config["pipelining"] == "secondary_wait"
    t = wait.trace.set_index(["frame", "task"])
    assert (t.loc[(1, "render1"), "start_ns"], t.loc[(1, "render1"), "end_ns"]) == (384, 704)
    assert (t.loc[(1, "h2d1"), "start_ns"], t.loc[(1, "h2d1"), "end_ns"]) == (832, 896)
    assert (t.loc[(1, "composite"), "start_ns"], t.loc[(1, "composite"), "end_ns"]) == (896, 912)
    assert wait.frames.present_ns.tolist() == [538, 922, 1306, 1690, 2074, 2458]
    lock = simulate(make_experiment(gpus=2, frames=4, iterations=20, pipelining="lockstep"))
    assert lock.frames.present_ns.tolist() == [538, 1076, 1614, 2152]
    assert lock.trace[(lock.trace.frame == 1) & (lock.trace.task == "render0")].start_ns.item() == 538
    full = simulate(make_experiment(gpus=2, frames=20, iterations=20, pipelining="full"))
    assert full.summary["frame_time_ms"] * 1e6 == pytest.approx(346, abs=1e-9)


def test_pipelining_mode_rejects_unknown():
    from mgpusim import InputError
    with pytest.raises(InputError, match="schedule.pipelining"):
        make_experiment(gpus=2, pipelining="partial")


def test_measured_run_recorded_before_a_new_option_still_matches():
    """A run recorded before `pipelining` existed lacks it: at its default that changes
    nothing, so the run still matches; set to something else, the difference is named."""
    from mgpusim import InputError
    from mgpusim.measured_check import check_recorded_config
    from mgpusim.program import recorded_inputs
    exp = make_experiment(gpus=2)
    config = {"schedule": "sort_first", "gpus": 2, "inputs": recorded_inputs(exp)}
    del config["inputs"]["schedule"]["pipelining"]
    check_recorded_config(config, exp, "old/summary.json")
    with pytest.raises(InputError, match="config.inputs.schedule.pipelining"):
        check_recorded_config(config, make_experiment(gpus=2, pipelining="lockstep"), "old/summary.json")
