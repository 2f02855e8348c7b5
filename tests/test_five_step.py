"""The five-step sort-first / sort-last schedule in the model."""
from __future__ import annotations

import copy

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
    for _frame, f in trace.groupby("frame"):
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
    from mgpusim.schedules.program import recorded_inputs
    from mgpusim.validation.measured_check import check_recorded_config
    exp = make_experiment(gpus=2)
    config = {"schedule": "sort_first", "gpus": 2, "inputs": recorded_inputs(exp)}
    del config["inputs"]["schedule"]["pipelining"]
    check_recorded_config(config, exp, "old/summary.json")
    with pytest.raises(InputError, match="config.inputs.schedule.pipelining"):
        check_recorded_config(config, make_experiment(gpus=2, pipelining="lockstep"), "old/summary.json")


def _costs(**composite) -> dict:
    prof = profile_dict(gpus=3)
    prof["gpus"][0]["costs"]["composite_sort_first"].update(composite)
    return prof


def test_sort_first_interleaved_strips_exact_timeline():
    """8x6 in 4 strips of [1, 1, 1, 3] rows, strip k on GPU k mod 2: GPU 0 rows 0 and 2 (16 px),
    GPU 1 rows 1 and 3-5 (32 px). At 20 ns per pixel: render0 0-320, render1 0-640; GPU 1's
    128 B cross at 1 B/ns: d2h 640-768, host copy -896, h2d -1024; the composite draws 32 px at
    1 ns plus 2 strips at 5 ns each: 1024-1066; present 1076."""
    r = simulate(make_experiment(_costs(ns_per_input=5.0), gpus=2, width=8, height=6, frames=3,
                                 iterations=20, tiles=4))
    assert r.config["strip_rows"] == (1, 1, 1, 3) and r.config["tile_rows"] == (2, 4)
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert (f0.loc["render0", "start_ns"], f0.loc["render0", "end_ns"]) == (0, 320)
    assert (f0.loc["render1", "start_ns"], f0.loc["render1", "end_ns"]) == (0, 640)
    assert (f0.loc["h2d1", "start_ns"], f0.loc["h2d1", "end_ns"]) == (896, 1024)
    assert (f0.loc["composite", "start_ns"], f0.loc["composite", "end_ns"]) == (1024, 1066)
    assert f0.loc["present", "end_ns"] == 1076
    assert r.config["contribution_bytes_per_frame"] == 128
    from mgpusim.schedules.program import build_program
    render = next(t for t in build_program(make_experiment(gpus=2, height=6, tiles=4)).templates[0]
                  if t.name == "render1")
    assert "one tile per GPU" in render.params["unsupported"]  # the runner refuses it


@pytest.mark.parametrize("opts, field", [({"tiles": 1}, "schedule.tiles"),
                                         ({"tiles": 7}, "schedule.tiles"),
                                         ({"tiles": 4, "tile_rows": [3, 3]}, "schedule.tiles")])
def test_sort_first_strips_bad_input(opts, field):
    from mgpusim import InputError
    from mgpusim.schedules.program import build_program
    with pytest.raises(InputError, match=field):
        build_program(make_experiment(gpus=2, height=6, **opts))


def test_balanced_strips_give_a_slower_gpu_fewer_exact_timeline():
    """GPU 1 twice as slow (2 ns per pixel-iteration), 8x12, 10 iterations, free composite:
    balanced tiles are 8 / 4 rows (640 + 10 present vs 640 ns), so of 6 strips of 2 rows GPU 0
    gets 4 and GPU 1 2, interleaved 0,1,0,0,1,0. Renders 0-640 on both; GPU 1's 32 px x 4 B =
    128 B cross at 1 B/ns: d2h 640-768, host copy -896, h2d -1024; composite 0 ns; present
    1024-1034."""
    from mgpusim.model.profile import parse_profile
    from mgpusim.schedules.experiment import parse_experiment
    prof = profile_dict(gpus=1)
    prof["gpus"][0]["costs"]["composite_sort_first"] = {"ns_per_pixel": 0.0, "ns_per_input": 0.0}
    slow = copy.deepcopy(prof["gpus"][0])
    slow["costs"]["fragment_loop"]["ns_per_pixel_iteration"] = 2.0
    prof["gpus"].append(slow)
    data = {"name": "t", "scene": {"width": 8, "height": 12, "passes": [
        {"name": "p", "kind": "fragment_loop", "iterations": 10}]},
        "schedule": {"name": "sort_first", "gpus": 2, "frames": 3, "warmup_frames": 1,
                     "tiles": 6, "balance": True}}
    r = simulate(parse_experiment(data, "t.toml", profile=parse_profile(prof, "p")))
    assert r.config["strip_gpus"] == (0, 1, 0, 0, 1, 0) and r.config["tile_rows"] == (8, 4)
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert (f0.loc["render0", "end_ns"], f0.loc["render1", "end_ns"]) == (640, 640)
    assert (f0.loc["h2d1", "start_ns"], f0.loc["h2d1", "end_ns"]) == (896, 1024)
    assert f0.loc["present", "end_ns"] == 1034
    data["schedule"]["balance"] = False  # round robin: 3 strips each, GPU 1 renders 6 rows
    even = simulate(parse_experiment(data, "t.toml", profile=parse_profile(prof, "p")))
    assert even.config["strip_gpus"] == (0, 1, 0, 1, 0, 1)
    assert even.trace[(even.trace.frame == 0) & (even.trace.task == "render1")].end_ns.item() == 960


def _objects_experiment(**sched):
    data = {"name": "t", "scene": {"width": 8, "height": 4, "objects": 8, "dataset_bytes": 8000,
                                   "passes": [{"name": "p", "kind": "mesh", "triangles": 800}]},
            "schedule": {"name": "sort_last", "gpus": 3, "frames": 3, "warmup_frames": 1, **sched}}
    from mgpusim.model.profile import parse_profile
    from mgpusim.schedules.experiment import parse_experiment
    return parse_experiment(data, "t.toml", profile=parse_profile(profile_dict(gpus=3), "p"))


def test_sort_last_whole_objects_exact_timeline():
    """8 statues of 100 triangles on 3 GPUs: 3/3/2 whole objects, renders of 300/300/200 ns at
    1 ns per triangle. 32 px x 6 B = 192 B per secondary at 1 B/ns: d2h1 300-492, d2h2
    200-392; the one memcpy thread takes host copies in submission order: 1 492-684, 2 684-876;
    h2d1 684-876, h2d2 876-1068; composite 64 px 1068-1132; present 1142. The runner draws
    triangles [0, 300), [300, 600), [600, 800); memory holds 3/8, 3/8, 2/8 of the data set."""
    from mgpusim.schedules.memory_check import memory_report
    from mgpusim.schedules.program import build_program
    exp = _objects_experiment()
    r = simulate(exp)
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert [f0.loc[f"render{i}", "end_ns"] for i in range(3)] == [300, 300, 200]
    assert (f0.loc["h2d2", "start_ns"], f0.loc["h2d2", "end_ns"]) == (876, 1068)
    assert f0.loc["present", "end_ns"] == 1142
    assert r.config["object_counts"] == (3, 3, 2)
    program = build_program(exp)
    ranges = [(t.params["first"], t.params["count"]) for t in program.templates[0] if t.step == "render"]
    assert ranges == [(0, 300), (300, 300), (600, 200)]
    used = memory_report(program, exp)
    assert used["gpu2"]["used_bytes"] - used["gpu1"]["used_bytes"] == 2000 - 3000
    given = simulate(_objects_experiment(object_counts=[2, 2, 4]))
    assert given.trace[(given.trace.frame == 0) & (given.trace.task == "render2")].end_ns.item() == 400


@pytest.mark.parametrize("counts", [[3, 3], [3, 3, 3], [4, 4, -0.5]])
def test_sort_last_object_counts_bad_input(counts):
    from mgpusim import InputError
    from mgpusim.schedules.program import build_program
    with pytest.raises(InputError, match="schedule.object_counts"):
        build_program(_objects_experiment(object_counts=counts))


def test_objects_and_strips_carry_their_placed_mesh_terms():
    """A whole-object share draws the triangle range the runner draws ([300, 600) of 800 for
    GPU 1 of 3/3/2), and a GPU drawing several strips sums its strips' placed terms."""
    from mgpusim.model.geometry import MeshView, Placement, coverage
    from mgpusim.schedules.program import build_program
    program = build_program(_objects_experiment())
    work = {t.name: t.work for t in program.templates[0] if t.step == "render"}
    assert work["render1"]["visible_triangle"] == coverage(MeshView(800, (8, 4), None, 300, 300)).triangles
    data = {"name": "t", "scene": {"width": 16, "height": 6, "passes": [
        {"name": "p", "kind": "mesh", "triangles": 400}]},
        "schedule": {"name": "sort_first", "gpus": 2, "frames": 3, "warmup_frames": 1, "tiles": 3}}
    from mgpusim.model.profile import parse_profile
    from mgpusim.schedules.experiment import parse_experiment
    exp = parse_experiment(data, "t.toml", profile=parse_profile(profile_dict(gpus=2), "p"))
    render0 = next(t for t in build_program(exp).templates[0] if t.name == "render0")
    expected = sum(coverage(Placement((16, 6), (0, y, 16, 2)).mesh_view(400)).triangles for y in (0, 4))
    assert render0.work["visible_triangle"] == expected


def test_five_step_binds_filters_to_their_tiles_and_a_mesh_to_depth():
    """A pass a later filter samples renders into a tile image of its own, which the filter
    reads (a temporal filter: the target of the previous frame, double-buffered); a mesh drawn
    into the target gives it depth, while sort-first still downloads colour only."""
    from mgpusim.model.profile import parse_profile
    from mgpusim.schedules.experiment import parse_experiment
    from mgpusim.schedules.program import build_program
    prof = parse_profile(profile_dict(gpus=2), "p")

    def program(passes):
        data = {"name": "t", "scene": {"width": 8, "height": 4, "passes": passes},
                "schedule": {"name": "sort_first", "gpus": 2, "frames": 3, "warmup_frames": 1}}
        return build_program(parse_experiment(data, "t", profile=prof))
    loop = {"name": "a", "kind": "fragment_loop", "iterations": 5}
    taa = program([loop, {"name": "taa", "kind": "filter", "iterations": 5, "inputs": 2}])
    tasks = {t.name: t for t in taa.templates[0]}
    res = {r.name: r for r in taa.resources}
    assert tasks["render1.taa"].reads == ("gpu1.pass.a", "gpu1.target")
    assert tasks["render1.taa"].params["read_offsets"] == (0, -1)
    assert tasks["render0.taa"].reads == ("gpu0.pass.a", "gpu0.frame")
    assert (res["gpu1.pass.a"].width, res["gpu1.pass.a"].height) == (8, 2)
    assert res["gpu0.frame"].buffers == 2 and res["gpu1.target"].buffers == 2
    mesh = program([{"name": "m", "kind": "mesh", "triangles": 100}])
    res = {r.name: r for r in mesh.resources}
    assert res["gpu0.frame"].depth and res["gpu1.target"].depth and not res["gpu0.input1"].depth
    d2h = next(t for t in mesh.templates[0] if t.name == "d2h1")
    assert d2h.params["depth"] is False and d2h.bytes == 8 * 2 * 4
