"""CPU-emulated GPUs (lavapipe): simulated GPUs' passes share the host's cores."""
from __future__ import annotations

import simpy

from mgpusim import simulate
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import CopyTask, PassTask, QueueRef
from mgpusim.sim.channel import PassWork
from mgpusim.sim.executors import SharedCores
from tests.conftest import make_experiment, profile_dict


def lavapipe_profile(cores: int, threads: int | None) -> dict:
    prof = profile_dict(gpus=2)
    prof["host"].update(cpu_cores=cores, gpus_share_cpu=True)
    if threads is not None:
        prof["gpus"][0]["cpu_threads"] = threads
    return prof


def renders(exp, names=("render0", "render1")) -> dict:
    t = simulate(exp).trace
    f0 = t[t.frame == 0].set_index("task")
    return {name: int(f0.loc[name, "end_ns"] - f0.loc[name, "start_ns"]) for name in names}


def test_concurrent_renders_share_the_cores():
    # 8x4 sort-first, 2 tiles of 16 px x 100 iterations = 1600 ns each on an idle machine.
    alone = renders(make_experiment(lavapipe_profile(2, None), gpus=1, iterations=100, width=8, height=2),
                    names=("render0",))
    assert alone == {"render0": 1600}
    both = renders(make_experiment(lavapipe_profile(2, None), gpus=2, iterations=100))
    assert both == {"render0": 3200, "render1": 3200}  # 2 GPUs x 2 threads on 2 cores: half speed


def test_enough_cores_means_no_slowdown():
    both = renders(make_experiment(lavapipe_profile(4, 2), gpus=2, iterations=100))
    assert both == {"render0": 1600, "render1": 1600}
    result = simulate(make_experiment(lavapipe_profile(4, 2), gpus=2, iterations=100))
    assert result.summary["effects"]["cpu_contention"] is True


def test_real_gpus_report_no_cpu_effect():
    assert "cpu_contention" not in simulate(make_experiment(gpus=2)).summary["effects"]


def test_passes_of_one_kind_take_turns_on_the_cores_without_loss():
    """4 rasterizer threads of two fragment-loop renders on 2 cores at 80% efficiency: the
    loss is for different work mixed on the cores (tests/test_channel.py); two passes of one
    kind share them evenly, 1600 * 2 = 3200 ns each."""
    prof = lavapipe_profile(2, None)
    prof["host"]["oversubscribed_efficiency"] = 0.8
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 3200, "render1": 3200}
    alone = renders(make_experiment(prof, gpus=1, iterations=100, width=8, height=2), names=("render0",))
    assert alone == {"render0": 1600}  # not oversubscribed: full speed


def test_dispatch_delays_tasks_fed_by_another_device():
    prof = profile_dict(gpus=2)
    prof["host"]["dispatch_ns"] = 7
    base = simulate(make_experiment(gpus=2, frames=3)).trace
    slow = simulate(make_experiment(prof, gpus=2, frames=3)).trace
    first = lambda t: t[t.frame == 0].set_index("task")  # noqa: E731
    # d2h1 follows render1 on the same device: no dispatch; host_copy1 and h2d1 each wait 7 ns.
    assert first(slow).loc["d2h1", "start_ns"] == first(base).loc["d2h1", "start_ns"]
    assert first(slow).loc["h2d1", "start_ns"] == first(base).loc["h2d1", "start_ns"] + 14


def test_submit_thread_submits_in_order_after_waking():
    """dispatch 100 ns, submit 50 ns: the primary's h2d is submitted 150 ns after the host copy
    ends; the composite behind it needs 50 ns more of the submit thread, but the 64 ns upload
    outlasts that, so it starts when the upload ends."""
    prof = profile_dict(gpus=2)
    prof["host"].update(dispatch_ns=100, submit_ns=50)
    t = simulate(make_experiment(prof, gpus=2, frames=3)).trace
    f0 = t[t.frame == 0].set_index("task")
    assert f0.loc["h2d1", "start_ns"] == f0.loc["host_copy1", "end_ns"] + 150
    assert f0.loc["composite", "start_ns"] == f0.loc["h2d1", "end_ns"]
    assert f0.loc["render0", "start_ns"] == 50  # even the first task waits to be submitted


def test_a_pass_that_keeps_fewer_cores_busy_is_slowed_less():
    """fragment_loop measured to keep 1 core busy (lavapipe's serial mesh binning, say): two
    GPUs rendering at once on 2 cores each get their one core, so neither is slowed; at 1.5
    cores each they share 2 cores at 1 core each: 1600 * 1.5 = 2400 ns."""
    prof = lavapipe_profile(2, None)
    prof["gpus"][0]["costs"]["fragment_loop"]["cores"] = 1.0
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 1600, "render1": 1600}
    prof["gpus"][0]["costs"]["fragment_loop"]["cores"] = 1.5
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 2400, "render1": 2400}
    alone = renders(make_experiment(prof, gpus=1, iterations=100, width=8, height=2), names=("render0",))
    assert alone == {"render0": 1600}  # alone, the measured time whatever the cores


def test_a_pass_keeps_its_terms_cores_busy_weighted_by_their_time():
    """`term_cores`: the work of a listed term keeps its own cores busy, the fixed part and the
    other terms the pass's `cores`. 1600 ns of pixel iterations at 1 core beside 800 ns fixed
    at 2 cores keep (1600 + 1600) / 2400 = 4/3 cores busy: two such renders at once on 2 cores
    each run at 3/4 of their speed alone, 2400 -> 3200 ns; all of it at 1 core, no slowdown."""
    prof = lavapipe_profile(2, None)
    prof["gpus"][0]["costs"]["fragment_loop"].update(cores=2.0, term_cores={"pixel_iteration": 1.0})
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 1600, "render1": 1600}
    prof["gpus"][0]["costs"]["fragment_loop"]["fixed_ns"] = 800
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 3200, "render1": 3200}
    cost = parse_profile(prof, "t").gpus[0].costs["fragment_loop"]
    assert cost.cores_of({"pixel_iteration": 1600}) == (800 * 2 + 1600) / 2400
    assert cost.cores_of({}) == 2.0  # the fixed part alone


def test_term_cores_are_checked():
    import pytest

    from mgpusim.model.errors import InputError
    prof = lavapipe_profile(2, None)
    prof["gpus"][0]["costs"]["fragment_loop"].update(cores=2.0, term_cores={"pixel_iteraton": 1.0})
    with pytest.raises(InputError, match="did you mean 'pixel_iteration'"):
        parse_profile(prof, "t")
    prof["gpus"][0]["costs"]["fragment_loop"] = {"ns_per_pixel_iteration": 1.0,
                                                 "term_cores": {"pixel_iteration": 1.0}}
    with pytest.raises(InputError, match="needs the pass's own `cores`"):
        parse_profile(prof, "t")


def test_driver_overhead_takes_a_core_from_the_other_gpu():
    """Each render keeps 1 core busy and costs 800 core-ns of driver work outside it: two GPUs
    at once put four flows on the two cores, half a core each, until the overheads end at
    1600 ns; the renders then finish their last 800 ns at a full core: 2400 ns. Alone, the
    render and its overhead fit the two cores (1600 ns); at scale 0 the overhead is off."""
    prof = lavapipe_profile(2, None)
    for gpu in prof["gpus"]:
        gpu["costs"]["fragment_loop"].update(cores=1.0, cpu_overhead_ns=800)
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 2400, "render1": 2400}
    alone = renders(make_experiment(prof, gpus=1, iterations=100, width=8, height=2), names=("render0",))
    assert alone == {"render0": 1600}
    prof["host"]["cpu_overhead_scale"] = 0.0
    assert renders(make_experiment(prof, gpus=2, iterations=100)) == {"render0": 1600, "render1": 1600}


def test_submit_thread_waking_competes_for_busy_cores():
    """A task fed by another device waits for its submit thread to wake (dispatch_ns). On
    real GPUs that is exactly dispatch_ns after the input; on CPU-emulated GPUs it is one
    core's work, so while both cores render it takes longer."""
    def wake_gaps(prof):
        t = simulate(make_experiment(prof, gpus=2, frames=6, iterations=2000)).trace
        by = t.set_index(["frame", "task"])
        return [int(by.loc[(f, "h2d1"), "start_ns"] - by.loc[(f, "host_copy1"), "end_ns"]) for f in range(1, 6)]
    real = profile_dict(gpus=2)
    real["host"]["dispatch_ns"] = 5000
    assert set(wake_gaps(real)) == {5000}
    emulated = lavapipe_profile(2, None)
    emulated["host"]["dispatch_ns"] = 5000
    gaps = wake_gaps(emulated)
    assert min(gaps) >= 5000 and max(gaps) > 5000


def test_driver_overhead_fields_are_checked():
    import pytest

    from mgpusim.model.errors import InputError
    from mgpusim.model.profile import parse_profile
    prof = lavapipe_profile(2, None)
    prof["gpus"][0]["costs"]["fragment_loop"]["cpu_overhead_ns"] = -1
    with pytest.raises(InputError, match="cpu_overhead_ns"):
        parse_profile(prof, "p")
    prof = lavapipe_profile(2, None)
    prof["host"]["cpu_overhead_scale"] = 1.5
    with pytest.raises(InputError, match="cpu_overhead_scale"):
        parse_profile(prof, "p")


def _secondary_starts(serial: bool, monkeypatch) -> list[int]:
    """Start times of the 3 secondaries' renders in one steady frame of a 4-GPU lavapipe
    sort-last run with a 0.3 ms dispatch: each waits for the primary's present two frames back,
    so all three submit threads wake on the same input."""
    from pathlib import Path

    from mgpusim.schedules.experiment import load_experiment, parse_overrides
    from mgpusim.sim.executors import SharedCores
    monkeypatch.setattr(SharedCores, "serial_dispatch", serial)
    exp = load_experiment(Path(__file__).resolve().parents[1] / "experiments/lavapipe/sort_last.toml",
                          parse_overrides(["schedule.gpus=4", "profile.host.dispatch_ns=300000"]))
    t = simulate(exp).trace
    f = t[(t.frame == 12) & t.task.isin(["render1", "render2", "render3"])]
    return sorted(int(v) for v in f.start_ns)


def test_host_threads_woken_at_once_take_turns_on_lavapipe(monkeypatch):
    """The runner's submit threads run Python under one interpreter lock: on CPU-emulated GPUs
    three threads woken by one input start their GPUs one after another (each waking is one
    core's work of dispatch_ns on the shared cores), not together."""
    together = _secondary_starts(False, monkeypatch)
    serial = _secondary_starts(True, monkeypatch)
    assert together[-1] - together[0] < 10_000
    gaps = [b - a for a, b in zip(serial, serial[1:])]
    assert all(g >= 300_000 for g in gaps), gaps


def _h200_secondary_starts(*sets: str) -> list[int]:
    """The 3 secondaries' render starts in one steady frame of the 4x H200 sort-first (each
    waits for the primary's present two frames back: three threads woken by one input)."""
    from pathlib import Path

    from mgpusim.schedules.experiment import load_experiment, parse_overrides
    exp = load_experiment(Path(__file__).resolve().parents[1] / "experiments/h200_x4/sort_first.toml",
                          parse_overrides(["schedule.frames=20", *sets]))
    t = simulate(exp).trace
    f = t[(t.frame == 12) & t.task.isin(["render1", "render2", "render3"])]
    return sorted(int(v) for v in f.start_ns)


def _h200_dispatch_ns() -> int:
    from pathlib import Path

    from mgpusim.model.profile import load_profile
    path = Path(__file__).resolve().parents[1] / "hardware_profiles" / "h200_x4.toml"
    return load_profile(path).host.dispatch_ns


def test_a_real_gpu_profile_may_say_its_host_threads_take_turns():
    """GPUs of their own wake their submit threads together unless the profile says the host's
    threads take turns (the Python executor's interpreter lock): then one dispatch_ns apart."""
    together = _h200_secondary_starts("profile.host.serial_dispatch=false")
    assert together[-1] - together[0] < 10_000
    serial = _h200_secondary_starts("profile.host.serial_dispatch=true")
    dispatch = _h200_dispatch_ns()
    assert [b - a for a, b in zip(serial, serial[1:])] == [dispatch, dispatch]
    assert _h200_secondary_starts() == together  # the 4x H200 profile (the native core)


def test_the_cores_know_each_pass_by_its_kind_and_a_pair_measured_kind_as_lossless():
    """What the host channel's loss rule reads: a pass's kind, lossless where the profile says
    its cores came from pairs; a copy is no pass."""
    prof = lavapipe_profile(2, None)
    for gpu in prof["gpus"]:
        gpu["costs"]["mesh"] = {"fixed_ns": 1000, "ns_per_triangle": 10, "cores_from_pairs": True}
    cores = SharedCores(simpy.Environment(), CostModel(parse_profile(prof, "test")))
    q = QueueRef(1, "graphics")
    assert cores._tag(PassTask("r", "render", q, "fragment_loop")) == PassWork("fragment_loop", False)
    assert cores._tag(PassTask("m", "render", q, "mesh")) == PassWork("mesh", True)
    assert cores._tag(CopyTask("c", "d2h", q, 64, "d2h")) is None


def test_a_real_gpu_host_may_share_one_interpreter():
    """With `host.shared_interpreter` the three secondaries woken by one present share the
    interpreter for their dispatch_ns: they start together (no turns), but each waking takes
    three times as long, and the submit work of the frame's other tasks slows them more."""
    alone = _h200_secondary_starts("profile.host.serial_dispatch=false")
    shared = _h200_secondary_starts("profile.host.shared_interpreter=true",
                                    "profile.host.serial_dispatch=false")
    loaded = _h200_secondary_starts("profile.host.shared_interpreter=true",
                                    "profile.host.serial_dispatch=false",
                                    "profile.host.submit_ns=50000")
    assert shared[-1] - shared[0] < 10_000  # processor sharing: they finish waking together
    # 3 wakings of dispatch_ns each at a third of the interpreter: done after 3x, not 1x
    assert shared[0] > alone[0] + 1.75 * _h200_dispatch_ns()
    assert loaded[0] > shared[0]


def test_a_shared_interpreter_run_repeats_and_reports_the_interpreter_busy():
    """Same input, same trace, with or without the fast-forward (which knows the interpreter's
    channel as it knows the host's cores); the summary says how busy the interpreter was, the
    figure the interpreter probe stands for on the real machine."""
    from pathlib import Path

    from mgpusim.schedules.experiment import load_experiment, parse_overrides
    sets = ["schedule.frames=300", "profile.host.shared_interpreter=true", "profile.host.submit_ns=50000",
            "profile.host.dispatch_ns=200000"]  # the Python executor's, on its runs
    exp = load_experiment(Path(__file__).resolve().parents[1] / "experiments/h200_x4/sort_first.toml",
                          parse_overrides(sets))
    a, b = simulate(exp), simulate(exp)
    assert a.trace.equals(b.trace)
    slow = simulate(exp, fast_forward=False)
    assert a.summary["frame_time_ms"] == slow.summary["frame_time_ms"]
    assert a.summary["latency_ms"] == slow.summary["latency_ms"]
    assert 0.2 < a.summary["utilization"]["host.interpreter"] < 1
