"""The effects the source systems lost time to, each on a small hand-computed timeline: the
thesis's per-frame host loop (threads started and joined, a wait for the queue after every
submit, command recording, a barrier per frame), host copies of uncached memory, the particle
thesis's one-GPU path through the host, graphics and compute sharing one GPU, and copy
granularity on a copy engine."""
from __future__ import annotations

import pytest

from mgpusim import InputError, simulate
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import CpuTask, PassTask, QueueRef
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.program import build_program
from mgpusim.sim.effects import EFFECTS, choose_effects
from mgpusim.sim.engine import Engine
from tests.conftest import make_experiment, profile_dict
from tests.schedule_helpers import experiment, gpu, profile, rows, timed


def _host(gpus: int = 2, **host):
    prof = profile_dict(gpus=gpus)
    prof["host"].update(host)
    return prof


def test_as_built_loop_exact_timeline():
    """8x4 sort-first on 2 GPUs (render 16 px x 10 it = 160 ns; 64 B copies at 1 B/ns; the
    composite draws both 16 px tiles = 32 ns; present 10), hand-off 5 ns, a thread start 3 ns,
    a recording 2 ns. Frame 0: the main thread starts 3 threads (0-9); each GPU's thread wakes
    at 14 and records (14-16), its render is submitted 5 ns later (21-181); the host copy of
    the previous loop's contribution starts at 14 (14-78), the upload is recorded at 83-85 and
    runs 90-154; secondary 1 wakes at 186, records its download (186-188), which runs 193-257;
    the main thread, woken at 262, records the composite (262-264), which runs 269-301, then
    present 301-311. The next loop starts 5 ns after the present: 316."""
    exp = make_experiment(_host(dispatch_ns=5, thread_start_ns=3, record_ns=2), gpus=2, frames=4,
                          iterations=10, host_work="as_built")
    r = simulate(exp)
    want = {"cpu.launch": (0, 9), "cpu.record0": (14, 16), "cpu.record1": (14, 16), "render0": (21, 181),
            "render1": (21, 181), "host_copy1": (14, 78), "cpu.record_upload": (83, 85), "h2d1": (90, 154),
            "cpu.record_d2h1": (186, 188), "d2h1": (193, 257), "cpu.record_composite": (262, 264),
            "composite": (269, 301), "present": (301, 311)}
    assert {task: rows(r, task, 0)[0] for task in want} == want
    assert rows(r, "cpu.launch", 1) == [(316, 325)]
    assert r.frames.present_ns.tolist() == [311, 627, 943, 1259]
    threads = r.trace[r.trace.step == "host_loop"].groupby("task").engine.first().to_dict()
    assert threads["cpu.launch"] == "main" and threads["cpu.record_d2h1"] == "gpu1"
    assert simulate(exp, fidelity="analytic").frames.present_ns.tolist() == [311, 627, 943, 1259]


def test_as_built_one_gpu_records_waits_and_presents():
    """One GPU renders straight to the window: record (2), submit (+5), render 320, present 10,
    wake (+5) before the next recording: a 342 ns loop."""
    r = simulate(make_experiment(_host(dispatch_ns=5, record_ns=2), gpus=1, frames=3, iterations=10,
                                 host_work="as_built"))
    assert rows(r, "cpu.record0") == [(0, 2), (342, 344), (684, 686)]
    assert rows(r, "render0", 0) == [(7, 327)] and rows(r, "present", 0) == [(327, 337)]


def test_thread_starts_and_recordings_are_the_host_frame_work_effect():
    """Three GPUs: the main thread starts 5 threads (one per GPU, one per secondary's copy).
    Without costs the effect is not needed; forced off, the CPU tasks take no time."""
    exp = make_experiment(_host(3, thread_start_ns=7, record_ns=4), gpus=3, frames=3, iterations=10,
                          host_work="as_built")
    r = simulate(exp)
    assert rows(r, "cpu.launch", 0) == [(0, 35)] and rows(r, "cpu.record2", 0) == [(35, 39)]
    assert "host_frame_work" in r.summary["modelled_effects"]
    off = simulate(exp, effects={"host_frame_work": False})
    assert rows(off, "cpu.launch", 0) == [(0, 0)] and rows(off, "cpu.record2", 0) == [(0, 0)]
    plain = make_experiment(_host(3), gpus=3, frames=3, iterations=10, host_work="as_built")
    assert not EFFECTS["host_frame_work"].needed(build_program(plain), plain.profile)


def test_as_built_composites_every_contribution():
    """The reference code renders the primary's part offscreen too: the composite draws all
    N contributions (sort-first: the whole frame; sort-last: N full frames)."""
    sf = build_program(make_experiment(_host(3), gpus=3, host_work="as_built"))
    comp = next(t for t in sf.templates[0] if t.name == "composite")
    assert (comp.work["input"], comp.work["pixel"]) == (3, 32)
    sl = build_program(make_experiment(schedule="sort_last", gpus=2, host_work="as_built"))
    comp = next(t for t in sl.templates[0] if t.name == "composite")
    assert (comp.work["input"], comp.work["pixel"]) == (2, 64)


def test_as_built_refuses_other_pipelining_levels():
    with pytest.raises(InputError, match="schedule.pipelining"):
        build_program(make_experiment(gpus=2, host_work="as_built", pipelining="lockstep"))


def test_uncached_reads_exact():
    """The as-built host copy reads the secondary's uncached staging buffer: 64 B at 0.5 B/ns
    = 128 ns instead of 64; the overlapped schedule's host copy (cached) keeps 64 ns. The effect
    is needed only where the uncached rate is below a memcpy thread's."""
    slow = make_experiment(_host(uncached_read_gbps=0.5), gpus=2, frames=3, iterations=10,
                           host_work="as_built")
    r = simulate(slow)
    assert rows(r, "host_copy1", 0) == [(0, 128)]
    assert "uncached_reads" in r.summary["modelled_effects"]
    assert rows(simulate(slow, effects={"uncached_reads": False}), "host_copy1", 0) == [(0, 64)]
    cached = make_experiment(_host(uncached_read_gbps=0.5), gpus=2, frames=3, iterations=10)
    assert rows(simulate(cached), "host_copy1", 0)[0][1] - rows(simulate(cached), "host_copy1", 0)[0][0] == 64
    fast = make_experiment(_host(uncached_read_gbps=2.0), gpus=2, frames=3, iterations=10,
                           host_work="as_built")
    assert "uncached_reads" not in choose_effects(build_program(fast), fast.profile)
    assert simulate(slow, fidelity="analytic").frames.present_ns.tolist() == r.frames.present_ns.tolist()


ENGINE = [timed("shadow", 100), timed("geometry", 200), timed("lighting", 300)]


def test_particles_one_gpu_path_through_the_host_exact():
    """One GPU, update on its compute queue (500 particles, 500 ns), the 500 B vertex buffer
    down (500-1000 on the transfer queue), through the main thread's copy (1 B/ns: 1000-1500)
    and up (1500-2000); the draw waits for it (2000-2005), then lighting and present."""
    exp = experiment(profile(), "particles", ENGINE, gpus=1, frames=2, warmup=1, particles=500,
                     vertex_bytes_per_particle=1, particle_gpu=0, policy="wait", cpu_copy=True,
                     one_gpu_path="through_host")
    r = simulate(exp)
    assert rows(r, "particle_update", 0) == [(0, 500)]
    assert rows(r, "particles.d2h", 0) == [(500, 1000)] and rows(r, "cpu.particles", 0) == [(1000, 1500)]
    assert rows(r, "particles.h2d", 0) == [(1500, 2000)] and rows(r, "particle_render", 0) == [(2000, 2005)]
    assert rows(r, "present", 0) == [(2305, 2315)]
    t = r.trace.set_index(["frame", "task"])
    assert (t.loc[(0, "particles.d2h"), "device"], t.loc[(0, "particles.h2d"), "engine"]) == ("gpu0", "transfer")
    local = simulate(experiment(profile(), "particles", ENGINE, gpus=1, frames=2, warmup=1, particles=500,
                                vertex_bytes_per_particle=1, particle_gpu=0, policy="wait"))
    assert not (local.trace.step == "d2h").any()


def test_graphics_and_compute_not_concurrent_share_the_gpu():
    """One GPU whose graphics and compute queues do not run at once (overlap 1.0): the update
    (500 ns) runs at half speed beside the shadow pass (100 ns: 0-200) and the geometry pass
    (200 ns: 200-600), 300 ns of its work done; the draw waits for it, so it finishes alone:
    0-800 (with overlap 2.0 it would take 0-500)."""
    prof = profile(gpus=[dict(__import__("tests.schedule_helpers", fromlist=["gpu"]).gpu(count=1),
                              queue_overlap={"graphics_compute": 1.0})])
    r = simulate(experiment(prof, "particles", ENGINE, gpus=1, frames=2, warmup=1, particles=500,
                            vertex_bytes_per_particle=1, particle_gpu=0, policy="wait"))
    assert rows(r, "render.shadow", 0) == [(0, 200)] and rows(r, "particle_update", 0) == [(0, 800)]
    assert "shared_gpu" in r.summary["modelled_effects"]


def test_copy_granularity_on_a_copy_engine_exact():
    """Chunking a copy pays the copy engine's fixed cost per chunk: one 64 B download with a
    20 ns launch takes 20 + 64 ns; a copy engine capped at 0.5 B/ns takes 20 + 128 ns (the
    copy_engine_caps effect)."""
    prof = profile_dict()
    prof["gpus"][0]["copy"] = {"transfer": {"fixed_ns": 20}}
    r = simulate(make_experiment(prof, gpus=2, frames=3, iterations=10))
    assert rows(r, "d2h1", 0)[0][1] - rows(r, "d2h1", 0)[0][0] == 84
    prof["gpus"][0]["copy"] = {"transfer": {"fixed_ns": 20, "d2h_gbps": 0.5}}
    r = simulate(make_experiment(prof, gpus=2, frames=3, iterations=10))
    assert rows(r, "d2h1", 0)[0][1] - rows(r, "d2h1", 0)[0][0] == 148
    assert "copy_engine_caps" in r.summary["modelled_effects"]


def test_fast_forward_of_the_as_built_loop_is_exact():
    """The loop's CPU threads are part of the state the fast-forward compares: 2000 frames
    skipped ahead equal 2000 frames simulated one by one."""
    exp = make_experiment(_host(dispatch_ns=5, thread_start_ns=3, record_ns=2, uncached_read_gbps=0.5),
                          gpus=2, frames=2000, iterations=10, host_work="as_built")
    fast = simulate(exp, record_trace=False)
    slow = simulate(exp, record_trace=False, fast_forward=False)
    assert fast.summary["fast_forward"]["used"] is True
    assert fast.frames.present_ns.tolist() == slow.frames.present_ns.tolist()


def test_as_built_upload_waits_for_the_primary_render_without_a_transfer_queue():
    """GPUs with a graphics queue only (lavapipe): the main thread joins the primary's render
    thread before it records the upload. Same costs as the exact timeline above: render0 ends
    at 181, the main thread wakes at 186 and records the upload (186-188), which runs 193-257
    on the primary's graphics queue (with a transfer queue of its own it was recorded at 83)."""
    prof = _host(dispatch_ns=5, thread_start_ns=3, record_ns=2)
    prof["gpus"][0]["queues"] = {"graphics": 1}
    r = simulate(make_experiment(prof, gpus=2, frames=4, iterations=10, host_work="as_built"))
    assert rows(r, "cpu.record_upload", 0) == [(186, 188)]
    assert rows(r, "h2d1", 0) == [(193, 257)]
    t = r.trace.set_index(["frame", "task"])
    assert t.loc[(0, "h2d1"), "engine"] == "graphics"
    assert rows(r, "present", 0) == [(301, 311)]


def test_as_built_update_gap_sleeps_between_present_and_next_frame():
    """One GPU (record 2, submit +5, render 320, present 10) with a 100 ns update gap: the main
    thread wakes after the present (337 + 5) and sleeps 100 ns; the next recording follows on
    the same thread at once: a 442 ns loop. The gap is a sleep: on CPU-emulated GPUs sharing
    one core it slows nothing."""
    exp = make_experiment(_host(dispatch_ns=5, record_ns=2), gpus=1, frames=3, iterations=10,
                          host_work="as_built", update_gap_ns=100)
    r = simulate(exp)
    assert rows(r, "cpu.update_gap") == [(342, 442), (784, 884), (1226, 1326)]
    assert rows(r, "cpu.record0") == [(0, 2), (442, 444), (884, 886)]
    assert simulate(exp, fidelity="analytic").frames.present_ns.tolist() == r.frames.present_ns.tolist()
    shared = _host(dispatch_ns=5, record_ns=2, cpu_cores=1, gpus_share_cpu=True)
    r = simulate(make_experiment(shared, gpus=1, frames=3, iterations=10, host_work="as_built",
                                 update_gap_ns=100))
    assert rows(r, "cpu.update_gap", 0) == [(342, 442)]


def test_update_gap_needs_the_as_built_loop():
    with pytest.raises(InputError, match="schedule.update_gap_ns"):
        build_program(make_experiment(gpus=2, update_gap_ns=100))
    with pytest.raises(InputError, match="schedule.update_gap_ns"):
        make_experiment(gpus=2, host_work="as_built", update_gap_ns=-1)


def test_an_idle_cpu_task_takes_no_core_beside_a_pass():
    """A 1000 ns pass on a CPU-emulated GPU that has the host's one core, beside 600 ns of CPU
    work on the main thread: busy work shares the core while both run (the pass ends at 1600);
    a sleep of the same length leaves it at 1000."""
    prof = parse_profile({"name": "one core", "gpus": [gpu(count=1)],
                          "host": {"memory_bandwidth_gbps": 1.0, "memcpy_threads": 1, "memcpy_thread_gbps": 1.0,
                                   "cpu_cores": 1, "gpus_share_cpu": True}}, "one-core")
    ends = {}
    for idle in (False, True):
        tasks = (CpuTask("cpu.wait", "cpu", fixed_ns=600.0, idle=idle),
                 PassTask("present", "present", QueueRef(0, "graphics"), "timed", {"reference_ns": 1000.0}))
        program = FrameProgram("idle", 1, 1, 0, (tasks,))
        ends[idle] = int(Engine(program, CostModel(prof)).run().present_end[0])
    assert ends == {False: 1600, True: 1000}


def test_as_built_host_copy_parts_follow_bp_parallel_copy():
    """bp's `parallelCopy` splits a copy into parts of max(bytes / threads, 512 KiB): a
    1024x384 sort-first tile (1,572,864 B) on 12 hardware threads is 3 parts; 400 KiB is one."""
    prof = _host(memcpy_threads=12)
    program = build_program(make_experiment(prof, gpus=2, width=1024, height=768, iterations=10,
                                            host_work="as_built"))
    copy = next(t for t in program.templates[0] if t.name == "host_copy1")
    assert copy.bytes == 1024 * 384 * 4 and copy.parts(12) == 3
    small = build_program(make_experiment(prof, gpus=2, width=320, height=640, iterations=10,
                                          host_work="as_built"))
    assert next(t for t in small.templates[0] if t.name == "host_copy1").parts(12) == 1


def _three_gpu_as_built(mem_gbps: float, fidelity: str = "full"):
    prof = profile_dict(gpus=3, mem_gbps=mem_gbps)
    prof["host"].update(dispatch_ns=5, thread_start_ns=3, record_ns=2)
    exp = make_experiment(prof, gpus=3, width=8, height=6, frames=3, iterations=10, host_work="as_built")
    return simulate(exp, fidelity=fidelity)


def test_as_built_host_copies_of_every_secondary_run_at_once():
    """bp's hostCopyStep starts every secondary's parallelCopy at once, each on threads of its
    own, although the host has one memcpy thread: 3 GPUs on 8x6, two 64 B contributions (8x2
    px). Frame 1: the present of frame 0 at 333, the loop's launch 5 ns later starts 5 threads
    (338-353); both copies start 5 ns after it (358) and, host memory (2 B/ns) holding both at
    a thread's 1 B/ns, both end at 422; the upload is recorded 5 ns after them (427-429). On the
    pool of one thread the second copy would start at 422. The analytic level agrees."""
    r = _three_gpu_as_built(2.0)
    assert rows(r, "host_copy1", 1) == rows(r, "host_copy2", 1) == [(358, 422)]
    assert rows(r, "cpu.record_upload", 1) == [(427, 429)]
    engines = r.trace[r.trace.task.str.startswith("host_copy")].groupby("task").engine.unique()
    assert {k: list(v) for k, v in engines.items()} == {"host_copy1": ["host_copy1.thread0"],
                                                       "host_copy2": ["host_copy2.thread0"]}
    analytic = _three_gpu_as_built(2.0, "analytic")
    assert analytic.frames.present_ns.tolist() == r.frames.present_ns.tolist() == [333, 671, 1009]


def test_copies_on_threads_of_their_own_share_host_memory():
    """The same loop with host memory at 1 B/ns: the two copies at once cross at 0.5 B/ns each,
    128 ns (frame 1: present 358, launch 363-378, copies 383-511). The analytic level takes each
    copy alone (64 ns) and says so."""
    r = _three_gpu_as_built(1.0)
    assert rows(r, "host_copy1", 1) == rows(r, "host_copy2", 1) == [(383, 511)]
    assert "host_memory_sharing" in r.summary["modelled_effects"]
    analytic = _three_gpu_as_built(1.0, "analytic")
    assert rows(analytic, "host_copy1", 1) == [(358, 422)]
    assert any(a.startswith("host_memory_sharing") for a in analytic.summary["approximations"])


@pytest.mark.parametrize("fidelity", ["full", "analytic"])
def test_a_parallel_copy_starts_its_part_threads_one_after_another(fidelity):
    """A 1024x384 sort-first tile (1.5 MiB) on 3 hardware threads is 3 parts of 512 KiB, each on
    a thread parallelCopy starts in turn (host.thread_start_ns = 1000 each): part k starts
    (k + 1) us after the copy's thread wakes (launch end + 5 ns hand-off), and takes 524,288 ns
    at a thread's 1 B/ns (host memory wide enough for all three)."""
    prof = profile_dict(gpus=2, mem_gbps=100.0, threads=3)
    prof["host"].update(dispatch_ns=5, thread_start_ns=1000)
    exp = make_experiment(prof, gpus=2, width=1024, height=768, frames=3, iterations=1, host_work="as_built")
    r = simulate(exp, fidelity=fidelity)
    launch_end = rows(r, "cpu.launch", 1)[0][1]
    parts = sorted(rows(r, "host_copy1", 1))
    assert parts == [(launch_end + 5 + k * 1000, launch_end + 5 + k * 1000 + 524_288) for k in (1, 2, 3)]
    copies = r.trace[(r.trace.task == "host_copy1") & (r.trace.frame == 1)]
    assert sorted(copies.engine) == [f"host_copy1.thread{k}" for k in range(3)]
