"""Hardware what-ifs as overrides: `--set profile.<key>=<value>` changes the experiment's
profile before validation (PCIe generation and lanes, peer links, a GPU speed factor, the
GPU count, memcpy threads), with the same checks as the file's own values."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim import InputError, load_experiment, simulate
from mgpusim.cli import main
from mgpusim.model.profile import PCIE_LANE_GBPS, load_profile
from mgpusim.schedules.experiment import parse_overrides

ROOT = Path(__file__).resolve().parents[1]
SORT_FIRST = ROOT / "experiments" / "sort_first_tc1.toml"
AFR = ROOT / "experiments" / "afr_tc1.toml"
SHORT = {"schedule.frames": 16, "schedule.warmup_frames": 4}


def test_pcie_generation_and_lanes_change_the_link():
    base = load_experiment(SORT_FIRST).profile
    exp = load_experiment(SORT_FIRST, parse_overrides(["profile.gpus.0.link.pcie_gen=5",
                                                       "profile.gpus.0.link.lanes=8"]))
    link, old = exp.profile.gpus[0].link, base.gpus[0].link
    assert (link.pcie_gen, link.lanes) == (5, 8)
    ratio = PCIE_LANE_GBPS[5] * 8 / (PCIE_LANE_GBPS[3] * 16)
    assert link.bandwidth_gbps("h2d") == pytest.approx(old.bandwidth_gbps("h2d") * ratio)
    assert exp.profile.gpus[2].link == base.gpus[2].link  # another [[gpus]] table: unchanged


def test_a_faster_link_shortens_the_frame():
    slow = simulate(load_experiment(SORT_FIRST, {**SHORT, "profile.gpus.*.link.pcie_gen": 1}))
    fast = simulate(load_experiment(SORT_FIRST, {**SHORT, "profile.gpus.*.link.pcie_gen": 5}))
    assert fast.summary["latency_ms"] < slow.summary["latency_ms"]


def test_measured_bandwidths_scale_with_the_nominal_rate(tmp_path: Path):
    """h100.toml gives measured h2d/d2h rates: PCIe 5 -> 4 keeps their efficiency (x0.5); an
    explicit bandwidth override wins over the scaling."""
    path = ROOT / "hardware_profiles" / "h100.toml"
    base = load_profile(path).gpus[0].link
    assert base.h2d_gbps is not None and base.pcie_gen == 5
    halved = load_profile(path, {"gpus.0.link.pcie_gen": 4}).gpus[0].link
    assert halved.h2d_gbps == pytest.approx(base.h2d_gbps / 2)
    assert halved.d2h_gbps == pytest.approx(base.d2h_gbps / 2)
    given = load_profile(path, {"gpus.0.link.pcie_gen": 4, "gpus.0.link.h2d_gbps": 30.0}).gpus[0].link
    assert given.h2d_gbps == 30.0 and given.d2h_gbps == pytest.approx(base.d2h_gbps / 2)


def test_gpu_count_repeats_the_last_gpu_so_a_schedule_can_use_more():
    with pytest.raises(InputError, match="profile.gpu_count=4"):
        load_experiment(SORT_FIRST, {"schedule.gpus": 4})
    exp = load_experiment(SORT_FIRST, {**SHORT, "schedule.gpus": 4, "profile.gpu_count": 4})
    assert len(exp.profile.gpus) == 4 and exp.profile.gpus[3] == exp.profile.gpus[2]
    assert exp.profile.gpus[3].link.lanes == 8  # TC1's last GPU sits on x8
    assert simulate(exp).summary["fps"] > 0
    fewer = load_experiment(SORT_FIRST, {"profile.gpu_count": 2})
    assert len(fewer.profile.gpus) == 2


def test_peer_mesh_links_every_pair_and_copies_take_it():
    exp = load_experiment(AFR, {**SHORT, "schedule.gpus": 3,
                                "profile.peer_mesh": {"bandwidth_gbps": 50.0, "latency_ns": 2000}})
    pairs = {frozenset((p.a, p.b)) for p in exp.profile.peer_links}
    assert pairs == {frozenset(p) for p in ((0, 1), (0, 2), (1, 2))}
    steps = set(simulate(exp).trace["step"])
    assert "p2p" in steps and "h2d" not in steps  # frames cross over the peer links


def test_speed_factor_divides_pass_times():
    def render_ns(speed: float) -> float:
        result = simulate(load_experiment(SORT_FIRST, {**SHORT, "profile.gpus.*.speed": speed}))
        renders = result.trace[result.trace["step"] == "render"]
        return float((renders["end_ns"] - renders["start_ns"]).mean())
    assert render_ns(2.0) == pytest.approx(render_ns(1.0) / 2, rel=1e-6)


def test_memcpy_threads_bound_the_host_copy_threads():
    def threads_used(n: int) -> int:
        exp = load_experiment(SORT_FIRST, {**SHORT, "profile.host.memcpy_threads": n})
        host = simulate(exp).trace.query("device == 'host'")
        return host["engine"].nunique()
    assert threads_used(1) == 1
    assert threads_used(4) > 1


def test_profile_overrides_apply_to_a_profile_given_on_the_command_line():
    exp = load_experiment(SORT_FIRST, {"profile.host.memcpy_threads": 3},
                          profile=ROOT / "hardware_profiles" / "tc2.toml")
    assert exp.profile.name == "TC2" and exp.profile.host.memcpy_threads == 3


def test_profile_overrides_need_a_profile_file():
    prof = load_profile(ROOT / "hardware_profiles" / "tc1.toml")
    with pytest.raises(InputError, match="profile.host.memcpy_threads"):
        load_experiment(SORT_FIRST, {"profile.host.memcpy_threads": 3}, profile=prof)


def test_a_result_records_its_what_ifs():
    result = simulate(load_experiment(SORT_FIRST, {**SHORT, "profile.gpus.*.speed": 2.0}))
    assert result.config["profile_overrides"] == {"profile.gpus.*.speed": 2.0}
    assert "profile_overrides" not in simulate(load_experiment(SORT_FIRST, SHORT)).config


def test_what_ifs_from_the_command_line(tmp_path: Path, capsys):
    out = tmp_path / "o"
    assert main(["simulate", str(SORT_FIRST), "--out", str(out), "--set", "schedule.frames=16",
                 "--set", "schedule.gpus=4", "--set", "profile.gpu_count=4",
                 "--set", "profile.gpus.*.speed=1.5", "--set", "profile.gpus.*.link.pcie_gen=4"]) == 0
    assert "on 4 GPU(s)" in capsys.readouterr().out


@pytest.mark.parametrize("overrides", [
    {"gpus.0.link.pcie_gen": 4, "gpus.0.link.lanes": 10**400},
    {"gpus.0.link.pcie_gen": 4, "gpus.0.link.h2d_gbps": 10**400},
    {"gpus.0.link.pcie_gen": [4]},
    {"gpus": [1]},
    {"gpus.0": "x"},
    {"gpus.0.link": {"pcie_gen": 4}},
])
def test_odd_profile_overrides_are_input_errors(overrides):
    """The measured-rate scaling looks at the raw values before validation: odd ones must
    reach validation (one InputError), never break the scaling itself."""
    with pytest.raises(InputError):
        load_profile(ROOT / "hardware_profiles" / "h100.toml", overrides)
