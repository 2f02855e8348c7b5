"""Particle offload: exact 'wait' timeline, 'new wait' never blocks the primary, skipped
updates skip their copies, update rate beside frame rate, no drift."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mgpusim import InputError, simulate
from tests.schedule_helpers import assert_no_drift, experiment, presents, profile, rows, timed

ENGINE = [timed("shadow", 100), timed("geometry", 200), timed("lighting", 300)]
PRIMARY_FRAME = 100 + 200 + 5 + 300 + 10  # passes + particle draw + present


def run(prof=None, **kw):
    kw.setdefault("particles", 500)
    kw.setdefault("vertex_bytes_per_particle", 1)
    kw.setdefault("host_copy", False)
    kw.setdefault("warmup", 1)
    return simulate(experiment(prof or profile(), "particles", ENGINE, **kw))


def test_wait_policy_exact_timeline():
    """Update 500 ns on GPU 1, 500 B down (500 ns) and up (500 ns); the draw waits for them."""
    r = run(frames=2, policy="wait")
    assert rows(r, "particle_update", 0) == [(0, 500)]
    assert rows(r, "particles.d2h", 0) == [(500, 1000)] and rows(r, "particles.h2d", 0) == [(1000, 1500)]
    assert rows(r, "render.geometry", 0) == [(100, 300)]
    assert rows(r, "particle_render", 0) == [(1500, 1505)]
    assert rows(r, "present", 0) == [(1805, 1815)]


def test_new_wait_exact_skip_pattern():
    """The chain (1500 ns) outlasts a 615 ns frame: updates run in frames 0, 4, 7, 10, ...
    (submitted at present f-2), the others are skipped with their copies."""
    r = run(frames=14)
    ran = sorted(r.trace[r.trace.task == "particle_update"].frame)
    assert ran == [0, 4, 7, 10, 13]
    for task in ("particles.d2h", "particles.h2d"):
        assert sorted(r.trace[r.trace.task == task].frame) == ran
    assert presents(r) == [PRIMARY_FRAME * (f + 1) for f in range(14)]
    assert r.summary["skipped_tasks"]["particle_update"] == 9
    rates = r.summary["task_rates_hz"]
    assert rates["particle_update"] < rates["frames"]


@settings(max_examples=20, deadline=None)
@given(particles=st.integers(0, 200_000), gbps=st.sampled_from([0.05, 1.0, 7 / 3, 100.0]),
       host_copy=st.booleans(), fif=st.integers(1, 3))
def test_new_wait_never_blocks_the_primary(particles, gbps, host_copy, fif):
    r = run(profile(gbps=gbps), frames=30, particles=particles, host_copy=host_copy, fif=fif)
    assert presents(r) == [PRIMARY_FRAME * (f + 1) for f in range(30)]
    gfx = r.trace[(r.trace.device == "gpu0") & (r.trace.engine == "graphics")]
    assert not gfx.waits_for.str.contains("particle").any()


def test_update_on_primary_compute_queue_runs_beside_the_shadow_pass():
    r = run(frames=2, gpus=1, particle_gpu=0, policy="wait")
    assert rows(r, "particle_update", 0) == [(0, 500)]
    assert r.trace[r.trace.task == "particle_update"].engine.iloc[0] == "compute"
    assert rows(r, "particle_render", 0) == [(500, 505)]
    assert not r.trace.step.isin(["d2h", "h2d"]).any()


def test_rejects_bad_options():
    with pytest.raises(InputError, match="particle_gpu"):
        run(gpus=1)
    with pytest.raises(InputError, match="draw_after"):
        run(draw_after="nope")


@pytest.mark.parametrize("policy", ["wait", "new_wait"])
def test_20000_frames_no_drift(policy):
    r = simulate(experiment(profile(gbps=7 / 3), "particles", ENGINE, frames=20_000, particles=777,
                            vertex_bytes_per_particle=3, policy=policy), record_trace=False)
    assert assert_no_drift(r.frames.present_ns) <= 2


def test_a_follower_of_two_skip_chains_is_rejected():
    from mgpusim.model.costs import CostModel
    from mgpusim.model.errors import ScheduleError
    from mgpusim.model.profile import parse_profile
    from mgpusim.model.tasks import Dep, PassTask, QueueRef
    from mgpusim.schedules.base import FrameProgram
    from mgpusim.sim.engine import Engine
    from tests.conftest import profile_dict

    q = QueueRef(0, "graphics")
    tasks = (PassTask("a", "update", q, "present", {}, skip_if_busy=True),
             PassTask("b", "update", q, "present", {}, skip_if_busy=True),
             PassTask("c", "copy", q, "present", {}, (Dep("a"), Dep("b")), skip_if_busy=True),
             PassTask("present", "present", q, "present", {}, (Dep("c"),)))
    program = FrameProgram("two_chains", 1, 2, 0, (tasks,))
    with pytest.raises(ScheduleError, match="two skip chains"):
        Engine(program, CostModel(parse_profile(profile_dict(), "p")))


def test_cpu_tasks_on_the_main_thread_exact_timeline():
    """'wait', 50 ns of CPU work per frame, the main thread copies the 500 B itself at 1 B/ns.
    Frame 0: cpu.frame 0-50; update 50-550 on GPU 1; d2h 550-1050; the main thread waits for it
    and copies 1050-1550; h2d 1550-2050; draw 2050-2055, lighting -2355, present -2365.
    Frame 1: the main thread is free at 1550: cpu.frame 1550-1600, update 1600-2100, d2h -2600,
    copy 2600-3100, ... present 3915. The CPU-side wait sets the period: 50 + 500 + 500 + 500."""
    kw = dict(frames=4, policy="wait", cpu_copy=True, cpu_frame_us=0.05)
    r = run(**kw)
    assert rows(r, "cpu.frame") == [(0, 50), (1550, 1600), (3100, 3150), (4650, 4700)]
    assert rows(r, "cpu.particles", 0) == [(1050, 1550)] and rows(r, "particles.h2d", 0) == [(1550, 2050)]
    assert rows(r, "particle_update", 1) == [(1600, 2100)]
    assert rows(r, "render.shadow", 2) == [(3915, 4015)]
    assert presents(r) == [2365, 3915, 5465, 7015]
    cpu = r.trace[r.trace.step.isin(["cpu", "cpu_copy"])]
    assert set(zip(cpu.device, cpu.engine)) == {("host", "main")}
    assert "host_copy" not in set(r.trace.step)
    analytic = simulate(experiment(profile(), "particles", ENGINE, particles=500,
                                   vertex_bytes_per_particle=1, host_copy=False, warmup=1, **kw),
                        fidelity="analytic")
    assert presents(analytic) == presents(r)


def test_cpu_copy_under_new_wait_never_blocks_the_primary():
    r = run(frames=14, cpu_copy=True)
    ran = sorted(r.trace[r.trace.task == "particle_update"].frame)
    assert sorted(r.trace[r.trace.task == "cpu.particles"].frame) == ran and len(ran) < 14
    assert presents(r) == [PRIMARY_FRAME * (f + 1) for f in range(14)]


def test_cpu_tasks_are_refused_by_the_runner_and_checked():
    from mgpusim.schedules.program import build_program
    program = build_program(experiment(profile(), "particles", ENGINE, cpu_frame_us=1.0))
    cpu = next(t for t in program.templates[0] if t.name == "cpu.frame")
    assert "simulated only" in cpu.params["unsupported"]
    with pytest.raises(InputError, match="schedule.cpu_frame_us"):
        experiment(profile(), "particles", ENGINE, cpu_frame_us=-1.0)


@pytest.mark.parametrize("policy", ["wait", "new_wait"])
def test_cpu_copy_fast_forward_is_exact(policy):
    exp = experiment(profile(), "particles", ENGINE, frames=2000, particles=500,
                     vertex_bytes_per_particle=1, host_copy=False, warmup=1, policy=policy,
                     cpu_copy=True, cpu_frame_us=0.05)
    fast, slow = simulate(exp, record_trace=False), simulate(exp, record_trace=False, fast_forward=False)
    assert fast.summary["fast_forward"]["used"] is True
    assert fast.frames.present_ns.tolist() == slow.frames.present_ns.tolist()
    assert fast.summary.get("skipped_tasks") == slow.summary.get("skipped_tasks")
