"""CPU work per frame (`schedule.cpu_frame_us`, any schedule) on the application's main
thread: exact timeline, host wake-up on a fence, the analytic level, the runner's refusal."""
from __future__ import annotations

import pytest

from mgpusim import InputError, simulate
from mgpusim.schedules.program import build_program
from tests.conftest import make_experiment, profile_dict


def test_cpu_frame_gates_the_frame_exact_timeline():
    """The 8x4 sort-first frame of test_five_step (render 320, copies 64 each, composite 16,
    present 10) behind 100 ns of CPU work. Frame 0: cpu.frame 0-100, renders 100-420, present
    628-638. Frame 1: cpu.frame 100-200 (the thread is free), render0 after present(0): 638-958,
    present 974-984. Frame 2: its CPU work waits for frame 0's present (two in flight): 638-738."""
    r = simulate(make_experiment(gpus=2, frames=4, iterations=20, cpu_frame_us=0.1))
    t = r.trace
    cpu = t[t.task == "cpu.frame"].sort_values("frame")
    assert list(zip(cpu.start_ns, cpu.end_ns))[:3] == [(0, 100), (100, 200), (638, 738)]
    assert set(zip(cpu.device, cpu.engine)) == {("host", "main")}
    f = t.set_index(["frame", "task"])
    assert (f.loc[(0, "render1"), "start_ns"], f.loc[(1, "render0"), "start_ns"]) == (100, 638)
    assert r.frames.present_ns.tolist()[:2] == [638, 984]
    analytic = simulate(make_experiment(gpus=2, frames=4, iterations=20, cpu_frame_us=0.1),
                        fidelity="analytic")
    assert analytic.frames.present_ns.tolist() == r.frames.present_ns.tolist()


def test_cpu_thread_wakes_dispatch_ns_after_a_gpu_input():
    prof = profile_dict()
    prof["host"]["dispatch_ns"] = 50
    r = simulate(make_experiment(prof, gpus=2, frames=4, iterations=20, cpu_frame_us=0.1))
    f = r.trace.set_index(["frame", "task"])
    assert f.loc[(2, "cpu.frame"), "start_ns"] == r.frames.present_ns.iloc[0] + 50


def test_cpu_frame_refused_by_the_runner_and_checked():
    program = build_program(make_experiment(gpus=2, cpu_frame_us=5.0))
    assert "simulated only" in program.templates[0][0].params["unsupported"]
    with pytest.raises(InputError, match="schedule.cpu_frame_us"):
        make_experiment(gpus=2, cpu_frame_us=-1.0)


def test_cpu_frame_beside_queues_that_share_a_gpu():
    """CPU tasks are the host's work: a GPU whose queues share it (queue_overlap) ignores
    them. The primary's compute queue updates 1000 particles (1000 ns) while its graphics
    queue renders 320 ns, after 100 ns of CPU work."""
    from tests.test_gpu_sharing import _particles, _profile
    r = simulate(_particles(_profile({"graphics_compute": 1.0}), cpu_frame_us=0.1))
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert f0.loc["cpu.frame", "end_ns"] == 100
    assert f0.loc["particle_update", "start_ns"] == 100 and f0.loc["render.geometry", "start_ns"] == 100
    assert "shared_gpu" in r.summary["modelled_effects"]


def test_fast_forward_with_cpu_tasks_is_exact():
    """A CPU thread's state is part of what the fast-forward compares: 3000 frames skipped
    ahead equal 3000 frames simulated one by one."""
    prof = profile_dict()
    prof["host"]["dispatch_ns"] = 30
    exp = make_experiment(prof, gpus=2, frames=3000, iterations=20, cpu_frame_us=0.25)
    fast = simulate(exp, record_trace=False)
    slow = simulate(exp, record_trace=False, fast_forward=False)
    assert fast.summary["fast_forward"]["used"] is True
    assert fast.frames.present_ns.tolist() == slow.frames.present_ns.tolist()
