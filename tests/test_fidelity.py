"""Fidelity levels, effects a scene calls for, the executors the engine is given, and the exact
fast-forward: each checked against the full event model on every shipped experiment."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.results.periodic import shifted_overlap
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.analytic import host_approximations
from mgpusim.sim.effects import EFFECTS, choose_effects, parse_effects
from mgpusim.sim.engine import Engine
from mgpusim.sim.executors import make_executors
from mgpusim.sim.simulation import build_program, simulate
from tests.conftest import make_experiment, profile_dict

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = [p for p in sorted(ROOT.glob("experiments/*.toml")) + sorted(ROOT.glob("experiments/*/*.toml"))
           if "[schedule]" in p.read_text()]
IDS = [str(p.relative_to(ROOT / "experiments")) for p in SHIPPED]
SHARING = {"link_sharing", "host_pcie", "host_memory_sharing", "shared_executor"}


def _summary(result) -> str:
    return json.dumps({k: v for k, v in result.summary.items() if k != "fast_forward"},
                      sort_keys=True, default=str)


def _same(a, b) -> None:
    assert _summary(a) == _summary(b)
    pd.testing.assert_frame_equal(a.frames, b.frames)
    pd.testing.assert_frame_equal(a.trace, b.trace)
    pd.testing.assert_frame_equal(a.links.reset_index(drop=True), b.links.reset_index(drop=True))


def test_shipped_experiments_found():
    assert len(SHIPPED) >= 12


# ----- fast-forward -----------------------------------------------------------------------
@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_fast_forward_changes_nothing(path: Path):
    """Same summary, trace, frames and links with the fast-forward on and off, at the shipped
    length and at a length where the repeat is extrapolated over hundreds of frames."""
    used = []
    for frames in (None, 400):
        exp = load_experiment(path, {"schedule.frames": frames} if frames else None)
        off, on = simulate(exp, fast_forward=False), simulate(exp, fast_forward=True)
        _same(off, on)
        assert off.summary["fast_forward"] == {"used": False, "why": "off"}
        used.append(on.summary["fast_forward"]["used"])
    if path.name != "sort_last_tc1.toml":  # its second GPU drifts for ~1,000 frames before repeating
        assert used[-1], "the 400-frame run should have repeated"


def test_fast_forward_long_run_streams_the_same_chunks():
    exp = load_experiment(ROOT / "experiments" / "h200" / "sort_first.toml", {"schedule.frames": 3000})
    off, on = simulate(exp, fast_forward=False), simulate(exp)
    assert on.summary["fast_forward"]["frames_skipped"] > 2900
    chunks = list(on.trace_chunks(rows_per_chunk=5000))
    assert len(chunks) > 3
    pd.testing.assert_frame_equal(pd.concat(chunks, ignore_index=True), off.trace)
    _same(off, on)


def test_fast_forward_with_skipped_tasks_counts_them():
    exp = load_experiment(ROOT / "experiments" / "particles_machine.toml", {"schedule.frames": 500})
    off, on = simulate(exp, fast_forward=False), simulate(exp)
    assert on.summary["fast_forward"]["used"]
    assert on.summary.get("skipped_tasks") == off.summary.get("skipped_tasks")
    assert on.summary.get("task_rates_hz") == off.summary.get("task_rates_hz")


@settings(max_examples=300, deadline=None)
@given(s=st.integers(-50, 50), d=st.integers(0, 40), t=st.integers(0, 15), copies=st.integers(0, 12),
       lo=st.integers(-20, 80), w=st.integers(0, 120))
def test_shifted_overlap_matches_brute_force(s, d, t, copies, lo, w):
    e, hi = s + d, lo + w
    brute = sum(max(0, min(e + j * t, hi) - max(s + j * t, lo)) for j in range(copies + 1))
    assert shifted_overlap(s, e, t, copies, lo, hi) == brute


# ----- effects ----------------------------------------------------------------------------
def test_parse_effects():
    assert parse_effects("+link_sharing,-task_gaps") == {"link_sharing": True, "task_gaps": False}
    for bad in ("link_sharing", "+nope", "+"):
        with pytest.raises(InputError, match="--effects"):
            parse_effects(bad)


def test_effects_a_scene_needs():
    one = make_experiment(gpus=1)
    prog = build_program(one)
    needed = choose_effects(prog, one.profile)
    assert "link_sharing" not in needed and "host_memory_sharing" not in needed
    assert "shared_executor" not in needed and "host_submission" not in needed
    tc1 = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml")
    assert "host_memory_sharing" in choose_effects(build_program(tc1), tc1.profile)
    lp = load_experiment(ROOT / "experiments" / "lavapipe" / "sort_first.toml")
    full = choose_effects(build_program(lp), lp.profile)
    assert "shared_executor" in full
    assert not SHARING & choose_effects(build_program(lp), lp.profile, "queues")


def test_shared_executor_cannot_be_forced_on_real_gpus():
    exp = make_experiment(gpus=2)
    with pytest.raises(InputError, match="shared_executor"):
        simulate(exp, effects={"shared_executor": True})


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_forcing_unneeded_effects_on_changes_nothing(path: Path):
    exp = load_experiment(path)
    needed = choose_effects(build_program(exp), exp.profile)
    base = simulate(exp, fast_forward=False)
    forced = [n for n, e in EFFECTS.items() if n not in needed and e.forceable]
    assert forced, "every shipped experiment leaves some effect out"
    for name in forced:
        other = simulate(exp, effects={name: True}, fast_forward=False)
        assert name in other.summary["modelled_effects"]
        pd.testing.assert_frame_equal(base.trace, other.trace)
        pd.testing.assert_frame_equal(base.frames, other.frames)


def test_turning_a_needed_effect_off_is_seen():
    # two host-copy parts at one thread's speed each on host memory of one thread's speed
    two = make_experiment(profile_dict(gpus=3, threads=4, mem_gbps=1.0, thread_gbps=1.0), gpus=3,
                          width=1024, height=1024)
    full = simulate(two)
    off = simulate(two, effects={"host_memory_sharing": False})
    assert "host_memory_sharing" not in off.summary["modelled_effects"]
    assert off.summary["frame_time_ms"] < full.summary["frame_time_ms"]
    prof = profile_dict(gpus=2)
    prof["host"]["submit_ns"] = 500
    exp = make_experiment(prof, gpus=2)
    assert not simulate(exp).frames.equals(simulate(exp, effects={"host_submission": False}).frames)


# ----- executors --------------------------------------------------------------------------
def test_engine_runs_on_the_executors_it_is_given():
    """Real GPUs given one pool of 4 host cores behave like a CPU-emulated machine."""
    prof = profile_dict(gpus=2)
    exp = make_experiment(prof, gpus=2, iterations=100)
    program, costs = build_program(exp), CostModel(exp.profile)
    own = Engine(program, costs).run()
    pooled = Engine(program, costs, executors=lambda env: make_executors(env, costs, shared=True)).run()
    assert "host.cpu" in pooled.channels and "host.cpu" not in own.channels
    prof["host"].update(gpus_share_cpu=True)
    lava = simulate(make_experiment(prof, gpus=2, iterations=100), fast_forward=False)
    rows = sorted(r[4:7] for r in pooled.rows)
    assert rows == sorted(tuple(x) for x in lava.trace[["task", "start_ns", "end_ns"]].itertuples(index=False))


# ----- fidelity levels --------------------------------------------------------------------
def _analytic_cases() -> list[tuple[Path, dict]]:
    """Shipped experiments (and host-copy-free variants) where the scene shares no resource."""
    cases = []
    for path in SHIPPED:
        for sets in ({}, {"schedule.host_copy": False}):
            try:
                exp = load_experiment(path, sets)
            except InputError:
                continue
            prog = build_program(exp)
            skips = any(t.skip_if_busy for ts in prog.templates for t in ts)
            if (not skips and not SHARING & choose_effects(prog, exp.profile)
                    and not host_approximations(exp.profile.host)):
                cases.append((path, sets))
    return cases


ANALYTIC = _analytic_cases()


def test_analytic_has_cases_of_every_kind():
    names = {p.name for p, _ in ANALYTIC}
    assert len(ANALYTIC) >= 8
    assert {"pipelining_miniengine_pcie3x8.toml", "sort_first_tc1.toml", "afr_tc1.toml"} <= names


@pytest.mark.parametrize("case", ANALYTIC, ids=[f"{p.name}{'-' + ','.join(s) if s else ''}" for p, s in ANALYTIC])
def test_analytic_equals_full_model_where_nothing_is_shared(case):
    path, sets = case
    exp = load_experiment(path, {**sets, "schedule.frames": 300})
    full, analytic = simulate(exp, fast_forward=False), simulate(exp, fidelity="analytic")
    pd.testing.assert_frame_equal(full.frames, analytic.frames)
    for key in ("frame_time_ms", "latency_ms", "frame_time_jitter_ms", "window_ns"):
        assert full.summary[key] == analytic.summary[key]
    assert analytic.summary["effects"]["analytic_exact"] is True
    assert analytic.summary["fidelity"] == "analytic"


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_analytic_equals_queues_level(path: Path):
    exp = load_experiment(path)
    queues, analytic = simulate(exp, fidelity="queues"), simulate(exp, fidelity="analytic")
    bounds = host_approximations(exp.profile.host)
    if bounds:  # host rules the recurrence leaves out (the 4x H200 profile's turns): a bound
        assert set(bounds) <= set(analytic.summary["effects"]["analytic_approximations"])
        assert analytic.summary["frame_time_ms"] <= queues.summary["frame_time_ms"]
        return
    pd.testing.assert_frame_equal(queues.frames, analytic.frames)
    assert queues.summary["fidelity"] == "queues"
    for key in ("skipped_tasks", "task_rates_hz"):
        assert queues.summary.get(key) == analytic.summary.get(key)


@pytest.mark.parametrize("policy", ["new_wait", "wait"])
@pytest.mark.parametrize("gpu", [0, 1])
def test_analytic_skips_as_the_event_model(policy: str, gpu: int):
    exp = load_experiment(ROOT / "experiments" / "particles_machine.toml",
                          {"schedule.frames": 2000, "schedule.policy": policy, "schedule.particle_gpu": gpu})
    queues = simulate(exp, fidelity="queues")
    for record in (True, False):
        analytic = simulate(exp, fidelity="analytic", record_trace=record)
        pd.testing.assert_frame_equal(queues.frames, analytic.frames)
        assert queues.summary.get("task_rates_hz") == analytic.summary.get("task_rates_hz")
    if policy == "new_wait" and gpu == 1:  # the slow integrated GPU cannot keep up
        assert analytic.summary["skipped_tasks"]["particle_update"] > 0


def test_analytic_says_what_it_approximates():
    lp = load_experiment(ROOT / "experiments" / "lavapipe" / "sort_first.toml")
    s = simulate(lp, fidelity="analytic").summary
    assert s["effects"]["analytic_exact"] is False
    assert any("shared_executor" in a for a in s["effects"]["analytic_approximations"])
    assert s["frame_time_ms"] < simulate(lp).summary["frame_time_ms"]  # an optimistic bound


def test_analytic_extrapolates_long_runs():
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 200_000})
    result = simulate(exp, fidelity="analytic", record_trace=False)
    assert result.summary["fast_forward"]["used"] and len(result.frames) == 200_000
    short = simulate(load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 2000}),
                     fidelity="analytic")
    pd.testing.assert_frame_equal(result.frames.iloc[:1990], short.frames.iloc[:1990])


def test_streamed_trace_file_is_the_whole_trace(tmp_path: Path):
    from mgpusim.io.writers import write_table, write_trace
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 600})
    on, off = simulate(exp), simulate(exp, fast_forward=False)
    assert on.compact
    window = on.trace_window(100, 140)
    full = off.trace
    pd.testing.assert_frame_equal(window, full[(full.frame >= 100) & (full.frame < 140)].reset_index(drop=True))
    assert on.compact  # the window did not build the whole trace
    for fmt in ("parquet", "csv"):
        write_trace(on, tmp_path / f"a.{fmt}", rows_per_group=700)
        write_trace(off, tmp_path / f"b.{fmt}")
        write_table(off.trace, tmp_path / f"c.{fmt}")
        read = pd.read_parquet if fmt == "parquet" else pd.read_csv
        pd.testing.assert_frame_equal(read(tmp_path / f"a.{fmt}"), read(tmp_path / f"b.{fmt}"))
        # the same values as the table pandas writes (the file's text columns are plain strings)
        a, c = read(tmp_path / f"a.{fmt}"), read(tmp_path / f"c.{fmt}")
        assert list(a.columns) == list(c.columns) and len(a) == len(c)
        for col in a.columns:
            assert (a[col].fillna("").astype(str) == c[col].fillna("").astype(str)).all(), col


@pytest.mark.parametrize("name", ["sort_first_tc1.toml", "afr_tc1.toml", "h200/sort_last.toml",
                                  "pipelining_miniengine_pcie3x8.toml"])
def test_sweep_lane_equals_analytic(name: str):
    import numpy as np

    from mgpusim.sim.analytic_lanes import sweep
    exp = load_experiment(ROOT / "experiments" / name)
    out = sweep(build_program(exp), CostModel(exp.profile), np.array([1.0, 2.0]), np.array([1.0, 1.0]))
    s = simulate(exp, fidelity="analytic").summary
    assert out["frame_time_ms"][0] == pytest.approx(s["frame_time_ms"], rel=1e-12)
    assert out["latency_ms"][0] == pytest.approx(s["latency_ms"], rel=1e-12)
    assert out["frame_time_ms"][1] > out["frame_time_ms"][0]  # slower passes, slower frames


def test_sweep_honours_the_gpus_speed_factor():
    """A sweep lane of a profile whose GPUs are 2x faster equals that profile simulated."""
    import numpy as np

    from mgpusim.sim.analytic_lanes import sweep
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"profile.gpus.*.speed": 2.0})
    out = sweep(build_program(exp), CostModel(exp.profile), np.array([1.0]), np.array([1.0]))
    assert out["frame_time_ms"][0] == pytest.approx(simulate(exp, fidelity="analytic").summary["frame_time_ms"],
                                                    rel=1e-12)


def test_fidelity_without_the_measured_data_is_one_clear_error(tmp_path: Path, capsys):
    from mgpusim.cli import main
    assert main(["fidelity", "--data", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "lacks the committed measured runs" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_fidelity_command_writes_the_table(tmp_path: Path):
    from mgpusim.bench.accuracy_cost import committed_sources, configurations
    from mgpusim.cli import main

    # the committed H200, H100 and lavapipe runs
    assert len(configurations(committed_sources(ROOT / "data"))) >= 100
    out = tmp_path / "new" / "folder"  # made as needed
    assert main(["fidelity", "--data", str(ROOT / "data"), "--out", str(out), "--repeats", "1"]) == 0
    table = pd.read_csv(out / "per_config.csv")
    assert set(table["level"]) == {"analytic", "queues", "full", "full, no fast-forward"}
    assert table["wall_ms"].gt(0).all()
    nvidia = table[table.machine.isin(["2x H200", "H100"])]
    assert nvidia["frame_time_error"].abs().max() < 0.1  # nothing shared there: every level agrees
    lavapipe = table[table.machine.str.startswith("lavapipe")]
    err = lavapipe.assign(e=lavapipe.frame_time_error.abs()).groupby("level")["e"].median()
    assert err["full"] < err["analytic"] and err["full"] < err["queues"]  # the shared cores matter
    key = ["machine", "config"]
    full = table[table.level == "full"].set_index(key)["frame_ms"]
    noff = table[table.level == "full, no fast-forward"].set_index(key)["frame_ms"]
    assert (full == noff.loc[full.index]).all()
    assert (out / "fidelity_pareto.png").stat().st_size > 10_000
    assert "| analytic | all |" in (out / "fidelity.md").read_text()
    dev = pd.read_csv(out / "deviations.csv").set_index("level")
    assert dev.loc["full", "worst_abs_deviation"] == 0  # the reference, with and without fast-forward
    assert dev.loc["full, no fast-forward", "worst_abs_deviation"] == 0
    assert dev.loc["analytic", "worst_abs_deviation"] > 0.3  # lavapipe: the shared cores matter


@st.composite
def _scenes(draw):
    """Small random machines and five-step scenes: shared or not, host effects, gaps."""
    prof = profile_dict(gpus=draw(st.integers(1, 4)), mem_gbps=draw(st.sampled_from([0.5, 1.0, 4.0])),
                        threads=draw(st.integers(1, 3)), thread_gbps=draw(st.sampled_from([0.5, 1.0])),
                        transfer=draw(st.integers(0, 2)), h2d=draw(st.sampled_from([0.25, 1.0])),
                        d2h=draw(st.sampled_from([0.5, 1.0])), latency=draw(st.sampled_from([0, 7])))
    prof["host"]["dispatch_ns"] = draw(st.sampled_from([0, 0, 13]))
    prof["host"]["submit_ns"] = draw(st.sampled_from([0, 0, 5]))
    prof["host"]["host_copy_wake_ns"] = draw(st.sampled_from([0, 0, 11]))
    prof["gpus"][0]["task_gap_ns"] = draw(st.sampled_from([0, 3]))
    if draw(st.booleans()):
        prof["host"].update(gpus_share_cpu=True, cpu_cores=draw(st.integers(1, 4)))
    gpus = draw(st.integers(1, prof["gpus"][0]["count"]))
    schedule = draw(st.sampled_from(["sort_first", "sort_last", "sort_first", "sort_last", "afr", "pipelining",
                                     "xr", "particles"]))
    kw = dict(schedule=schedule, gpus=gpus, frames=draw(st.integers(30, 120)),
              width=draw(st.sampled_from([64, 256, 1024])), height=draw(st.sampled_from([4, 64, 512])),
              iterations=draw(st.integers(1, 200)))
    if schedule.startswith("sort_"):
        kw["host_copy"] = draw(st.booleans())
    return prof, kw


def _make(scene):
    """The scene's experiment, or None where the schedule refuses it (e.g. too few GPUs)."""
    from mgpusim.model.errors import MgpusimError
    prof, kw = scene
    try:
        exp = make_experiment(prof, **kw)
        build_program(exp)
    except MgpusimError:
        return None
    return exp


@settings(max_examples=60, deadline=None)
@given(_scenes())
def test_fast_forward_exact_on_random_scenes(scene):
    exp = _make(scene)
    assume(exp is not None)
    _same(simulate(exp, fast_forward=False), simulate(exp))


@settings(max_examples=40, deadline=None)
@given(_scenes())
def test_analytic_exact_on_random_unshared_scenes(scene):
    exp = _make(scene)
    assume(exp is not None)
    if SHARING & choose_effects(build_program(exp), exp.profile):
        queues, analytic = simulate(exp, fidelity="queues"), simulate(exp, fidelity="analytic")
        pd.testing.assert_frame_equal(queues.frames, analytic.frames)
        return
    pd.testing.assert_frame_equal(simulate(exp).frames, simulate(exp, fidelity="analytic").frames)


def test_fast_forward_refuses_executors_it_cannot_describe():
    from mgpusim.sim import fastforward
    from mgpusim.sim.executors import Dedicated

    class Custom(Dedicated):
        """A device with state of its own (here none, but the fast-forward cannot know)."""

    exp = make_experiment(gpus=2, frames=200)
    program, costs = build_program(exp), CostModel(exp.profile)
    engine = Engine(program, costs, executors=lambda env: {n: Custom(env) for n in make_executors(env, costs, False)})
    raw = fastforward.run(engine)
    assert raw.fast_forward["used"] is False and "Custom" in raw.fast_forward["why"]


def test_cli_fidelity_and_effects(tmp_path: Path, capsys):
    from mgpusim.cli import main
    exp = str(ROOT / "experiments" / "sort_first_tc1.toml")
    assert main(["simulate", exp, "--fidelity", "analytic", "--out", str(tmp_path / "a")]) == 0
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["fidelity"] == "analytic" and (tmp_path / "a" / "trace.parquet").is_file()
    assert main(["simulate", exp, "--effects", "+link_sharing", "--no-fast-forward",
                 "--out", str(tmp_path / "b")]) == 0
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert "link_sharing" in summary["modelled_effects"] and summary["fast_forward"]["why"] == "off"
    capsys.readouterr()
    assert main(["simulate", exp, "--effects", "+link_sharin", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "did you mean +link_sharing" in err[0]
    assert not (tmp_path / "c").exists()


@settings(max_examples=40, deadline=None)
@given(_scenes())
def test_unshared_levels_bound_the_full_model(scene):
    """Sharing never speeds a task up and the timing is monotone: without link and host-memory
    sharing every frame presents no later (docs/fidelity.md). (Without the shared executor,
    CPU-emulated GPUs also copy over links instead of memcpy: not a bound, left out.)"""
    exp = _make(scene)
    assume(exp is not None and not exp.profile.host.gpus_share_cpu)
    if any(t.skip_if_busy for ts in build_program(exp).templates for t in ts):
        return  # skipping is not monotone: a later update may run where an earlier one was skipped
    full, queues = simulate(exp), simulate(exp, fidelity="queues")
    assert (queues.frames["present_ns"] <= full.frames["present_ns"]).all()


@pytest.mark.parametrize("name", ["sort_last_tc1.toml", "sort_first_tc1.toml"])
def test_without_a_trace_the_summary_does_not_depend_on_the_fast_forward(name: str):
    exp = load_experiment(ROOT / "experiments" / name, {"schedule.frames": 150})
    off, on = simulate(exp, record_trace=False, fast_forward=False), simulate(exp, record_trace=False)
    assert _summary(off) == _summary(on) and len(on.trace) == 0
    pd.testing.assert_frame_equal(off.frames, on.frames)


def test_sweep_refuses_skippable_schedules():
    import numpy as np

    from mgpusim.sim.analytic_lanes import sweep
    exp = load_experiment(ROOT / "experiments" / "particles_machine.toml")
    with pytest.raises(InputError, match="skippable"):
        sweep(build_program(exp), CostModel(exp.profile), np.ones(2), np.ones(2))


def test_written_outputs_do_not_depend_on_the_fast_forward(tmp_path: Path):
    """The windows of a compact trace (timeline, Perfetto) and the tables are the files the
    whole trace gives."""
    from mgpusim.io.writers import write_result
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 600})
    on, off = simulate(exp), simulate(exp, fast_forward=False)
    assert on.compact
    a = write_result(on, tmp_path / "on", trace_frames=50)
    b = write_result(off, tmp_path / "off", trace_frames=50)
    assert on.compact  # nothing built the whole trace
    assert (tmp_path / "on" / "trace.perfetto.json").read_text() == (tmp_path / "off" / "trace.perfetto.json").read_text()
    for name in ("trace", "frames", "links"):
        pd.testing.assert_frame_equal(pd.read_parquet(a[name]), pd.read_parquet(b[name]))
    assert a["timeline"].stat().st_size > 10_000
