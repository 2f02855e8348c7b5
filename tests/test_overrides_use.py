"""What-ifs that cannot mislead: a ``profile.`` override the model never reads for the
experiment is refused, naming it; a task slowed past the time bound by an override (host
copies included) names that override; a value beyond every shipped profile's is warned
about; a level that approximates lists what it leaves out; --frames past the run is clipped
with a note."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.model.errors import InputError, TimeBoundError
from mgpusim.model.profile import load_profile
from mgpusim.model.profile_reads import outside_shipped, read_paths, unused
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
TC1 = ROOT / "experiments" / "sort_first_tc1.toml"
LAVAPIPE = ROOT / "experiments" / "lavapipe" / "sort_first.toml"
SHORT = {"schedule.frames": 12, "schedule.warmup_frames": 4}


def _run(path: Path, fidelity: str = "full", **overrides):
    return simulate(load_experiment(path, {**SHORT, **overrides}), fidelity=fidelity)


def test_host_memory_bandwidth_is_unused_where_memcpys_are_core_work():
    with pytest.raises(InputError) as caught:
        _run(LAVAPIPE, **{"profile.host.memory_bandwidth_gbps": 1e-9})
    assert caught.value.field == "profile.host.memory_bandwidth_gbps"
    assert "unused by this experiment" in str(caught.value)


def test_the_same_key_is_used_where_host_copies_cross_host_memory():
    slow = _run(TC1, **{"profile.host.memory_bandwidth_gbps": 0.1}).summary["frame_time_ms"]
    assert slow > _run(TC1).summary["frame_time_ms"]


def test_a_cost_of_a_pass_kind_the_scene_lacks_is_unused():
    with pytest.raises(InputError, match="unused by this experiment") as caught:
        _run(TC1, **{"profile.gpus.*.costs.mesh.fixed_ns": 5.0})
    assert caught.value.field == "profile.gpus.*.costs.mesh.fixed_ns"


def test_a_value_that_switches_an_effect_off_is_used():
    """task_gap_ns = 0 is read to leave the gaps out: a sweep from 0 up is no unused key."""
    assert _run(TC1, **{"profile.gpus.*.task_gap_ns": 0}).summary == _run(TC1).summary


@pytest.mark.parametrize("path, key, value", [
    (TC1, "profile.gpus.*.speed", 1.0),
    (TC1, "profile.host.memcpy_threads", 12),
    (LAVAPIPE, "profile.host.cpu_cores", 2),
    (LAVAPIPE, "profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration", 0.148054),
])
def test_a_watched_run_gives_the_plain_runs_results(path, key, value):
    """The profile's own value as an override: the run that notes reads is the same run."""
    plain, watched = _run(path), _run(path, **{key: value})
    assert watched.summary == plain.summary
    assert watched.trace.equals(plain.trace)


@pytest.mark.parametrize("fidelity", ["full", "queues", "analytic"])
def test_a_host_copy_slowed_past_the_bound_names_the_override(fidelity):
    with pytest.raises(TimeBoundError) as caught:
        _run(TC1, fidelity, **{"profile.host.memory_bandwidth_gbps": 1e-9})
    assert caught.value.field == "profile.host.memory_bandwidth_gbps"
    assert "host_copy" in str(caught.value)


def test_a_speed_past_the_bound_names_the_speed_not_a_coefficient():
    with pytest.raises(TimeBoundError) as caught:
        _run(TC1, **{"profile.gpus.*.speed": 1e-12, "profile.host.memcpy_threads": 4})
    assert caught.value.field == "profile.gpus.*.speed"
    assert "profile.gpus.*.speed=1e-12" in str(caught.value)


def test_read_paths_map_override_keys_onto_what_the_model_reads():
    assert read_paths("gpus.1.costs.mesh.ns_per_triangle") == ["gpus.*.costs.mesh.ns_per.triangle"]
    assert read_paths("gpus.0.copy.transfer.h2d_gbps") == ["gpus.*.copy.transfer.caps_gbps.h2d"]
    assert "gpus.*.link.h2d_gbps" in read_paths("gpus.0.link.pcie_gen")  # measured rates scale with it
    assert read_paths("gpu_count") is None and read_paths("gpus.0.name") is None
    assert unused({"profile.host.dispatch_ns": 1, "profile.gpu_count": 3}, {"host.submit_ns"}) == \
        ["profile.host.dispatch_ns"]
    assert unused({"profile.gpus.0.link": {"pcie_gen": 4}}, {"gpus.*.link.lanes"}) == []


def test_values_beyond_every_shipped_profile_are_warned_about():
    profiles = [load_profile(ROOT / "hardware_profiles" / name) for name in ("tc1.toml", "lavapipe_2core.toml")]
    assert outside_shipped({"profile.host.memory_bandwidth_gbps": 45.0}, profiles) == []
    (low,) = outside_shipped({"profile.host.memory_bandwidth_gbps": 1e-3}, profiles)
    assert "profile.host.memory_bandwidth_gbps" in low and "30 to 59.8567" in low
    assert outside_shipped({"profile.gpus.1.task_gap_ns": 0}, profiles) == []  # tc1's default counts
    assert len(outside_shipped({"profile.gpus.0.task_gap_ns": 10 ** 9}, profiles)) == 1
    assert outside_shipped({"profile.gpus.*.costs.captured.fixed_ns": 1e9}, profiles[:1]) == []  # none has it
    assert outside_shipped({"profile.gpu_count": 64, "scene.width": 1e9}, profiles) == []  # not judged


def test_a_run_beyond_the_shipped_range_records_the_warning():
    summary = _run(TC1, **{"profile.host.memory_bandwidth_gbps": 1e-3}).summary
    (warning,) = summary["warnings"]
    assert warning.startswith("profile.host.memory_bandwidth_gbps = 0.001")
    assert "warnings" not in _run(TC1, **{"profile.host.memory_bandwidth_gbps": 40.0}).summary


def test_the_queues_level_lists_what_it_leaves_out():
    summary = _run(LAVAPIPE, "queues").summary
    names = [a.split(":")[0] for a in summary["approximations"]]
    assert "shared_executor" in names and "host_memory_sharing" in names
    assert "approximations" not in _run(LAVAPIPE).summary  # full is the reference
    no_host_copies = _run(TC1, "queues", **{"schedule.host_copy": False})
    assert no_host_copies.summary["approximations"] == []  # nothing this scene needs is omitted


def test_simulate_prints_warnings_approximations_and_clips_frames(tmp_path, capsys):
    args = ["simulate", str(TC1), "--no-progress", "--set", "schedule.frames=12", "--set",
            "schedule.warmup_frames=4"]
    assert main([*args, "--out", str(tmp_path / "a"), "--set", "profile.host.memory_bandwidth_gbps=1e-3",
                 "--fidelity", "queues", "--frames", "2:1000000"]) == 0
    out, err = capsys.readouterr()
    assert "warning: profile.host.memory_bandwidth_gbps = 0.001" in err
    assert "approximations" in out
    assert "--frames 2:1000000 runs past the run's 12 frames: timeline.png draws frames 2-11" in out
    assert main([*args, "--out", str(tmp_path / "b"), "--frames", "12:20"]) == 2
    assert "--frames" in capsys.readouterr().err


def test_sweep_lanes_give_each_point_its_own_warnings(tmp_path, monkeypatch):
    """A pass-cost lane beyond the shipped range warns in its own row, as its own run would."""
    from tests.test_sweep_lanes import _files, _per_point, _sweep, assert_same_table  # noqa: PLC0415

    grid = {"profile.gpus.*.costs.fragment_loop.fixed_ns": [20000.0, 1e9], "scene.width": [800, 1024]}
    df = _sweep(TC1, grid, tmp_path / "a")
    assert _files(tmp_path / "a")[0] == 4  # run as lanes
    warned = df["warnings.0"].notna().tolist()
    assert warned == [False, False, True, True]
    assert_same_table(df, _per_point(monkeypatch, TC1, grid, tmp_path / "b"))


def test_sweep_warns_on_stderr_and_an_unused_grid_key_fails_naming_it(tmp_path, capsys):
    args = ["sweep", str(TC1), "--set", "schedule.frames=12", "--set", "schedule.warmup_frames=4",
            "--fidelity", "analytic", "--workers", "1", "--no-progress"]
    assert main([*args, "--grid", "profile.host.memory_bandwidth_gbps=1e-3,40", "--out", str(tmp_path / "a")]) == 0
    assert "warning: 1 of 2 points depend on a value outside every shipped profile's" in capsys.readouterr().err
    assert main([*args, "--grid", "profile.host.busy_wake_ns=5,6", "--out", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err
    assert "every point failed" in err and "profile.host.busy_wake_ns: unused by this experiment" in err
