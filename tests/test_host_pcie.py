"""The host side of PCIe (host_pcie): copies of several GPUs in one direction share the host's
capacity, each also held to its own link; exact timelines computed by hand."""
from __future__ import annotations

from fractions import Fraction

import pytest
import simpy

from mgpusim import simulate
from mgpusim.model.errors import InputError
from mgpusim.model.profile import parse_profile
from mgpusim.sim.effects import EFFECTS, choose_effects
from mgpusim.sim.hostlink import HostLinkChannel
from mgpusim.sim.simulation import build_program
from tests.schedule_helpers import experiment, gpu, rows, timed


def run_links(capacity: int, links: dict[str, int], flows: list[tuple[str, int, int, Fraction | None]]):
    """End times of `flows` (link, start, bytes, cap) on links of the given B/ns behind a host
    channel of `capacity` B/ns."""
    env = simpy.Environment()
    channel = HostLinkChannel(env, "pcie.d2h", Fraction(capacity))
    ports = {name: channel.port(name, Fraction(bw)) for name, bw in links.items()}
    ends: list[int] = [0] * len(flows)

    def one(i: int, link: str, start: int, nbytes: int, cap: Fraction | None):
        yield env.timeout(start)
        yield ports[link].transfer(nbytes, cap)
        ends[i] = env.now

    for i, flow in enumerate(flows):
        env.process(one(i, *flow))
    env.run()
    return ends, channel


LINKS = {f"gpu{i}": 50 for i in range(4)}


def test_two_gpus_that_fit_the_host_cross_at_their_link_rates():
    ends, _ = run_links(120, LINKS, [("gpu0", 0, 5000, None), ("gpu1", 0, 5000, None)])
    assert ends == [100, 100]  # 50 + 50 <= 120: 5000 B at 50 B/ns each


def test_four_gpus_share_the_host_capacity():
    ends, ch = run_links(120, LINKS, [(f"gpu{i}", 0, 3000, None) for i in range(4)])
    assert ends == [100] * 4  # 30 B/ns each
    ends, ch = run_links(120, LINKS, [(f"gpu{i}", 0, 3000 if i < 3 else 6000, None) for i in range(4)])
    # 30 B/ns each until 100 ns; the last one's 3000 B left then cross alone at its link's 50
    assert ends == [100, 100, 100, 160]
    assert ch.busy == [(0, 160)] and ch.max_concurrent == 4 and ch.max_links == 4


def test_a_full_link_leaves_its_share_of_the_host_to_the_others():
    # host 120/4 = 30, but gpu0's two copies share its 50: 25 each; the others split the 70
    # left, 35 each: 2500 B / 25 = 100 ns, 3500 B / 35 = 100 ns
    ends, _ = run_links(120, LINKS, [("gpu0", 0, 2500, None), ("gpu0", 0, 2500, None),
                                     ("gpu1", 0, 3500, None), ("gpu2", 0, 3500, None)])
    assert ends == [100, 100, 100, 100]


def test_caps_and_rounding():
    # gpu0 capped at 10 B/ns; the others split 110: 110/3 B/ns; 3000 B in 81.8 ns -> 82
    ends, _ = run_links(120, LINKS, [("gpu0", 0, 1000, Fraction(10))] + [(f"gpu{i}", 0, 3000, None)
                                                                         for i in (1, 2, 3)])
    assert ends == [100, 82, 82, 82]


def test_a_later_copy_slows_the_running_ones():
    # gpu0..2 at 40 each (120/3 < 50) from 10 ns; gpu3 alone at 50 for 10 ns (500 B), then all
    # four at 30: gpu3's 2500 B left in 83.3 ns; gpu0..2's 3000 B ... see below
    ends, _ = run_links(120, LINKS, [("gpu3", 0, 3000, None)] + [(f"gpu{i}", 10, 3000, None) for i in range(3)])
    # 10..: 4 at 30; gpu3 has 2500 left -> ends 10 + 2500/30 = 93.3; by then the others moved
    # 2500 each, 500 left, 3 at 40: 12.5 ns more -> 105.8
    assert ends == [93, 106, 106, 106]


def h100_like(pcie: float | None) -> object:
    """Four GPUs whose links move 1 B/ns each way; the host side of d2h takes `pcie` B/ns."""
    host = {"memory_bandwidth_gbps": 1.0, "memcpy_threads": 1, "memcpy_thread_gbps": 1.0, "cpu_cores": 4}
    if pcie is not None:
        host["pcie_d2h_gbps"] = pcie
    return parse_profile({"name": "t", "host": host, "gpus": [gpu(count=4)]}, "test-profile")


def sort_first(prof, gpus: int = 4):
    return experiment(prof, "sort_first", [timed("fragment_loop", 1000)], gpus=gpus, frames=3,
                      width=8, height=4, warmup=0)


def test_sort_first_strips_share_the_host_side():
    """GPUs 1-3 end their strips at 1000 ns and copy 32 B each to the host: alone each at its
    link's 1 B/ns (32 ns); behind a 2 B/ns host side at 2/3 B/ns each (48 ns)."""
    plain = simulate(sort_first(h100_like(None)))
    shared = simulate(sort_first(h100_like(2.0)))
    for i in (1, 2, 3):
        assert rows(plain, f"d2h{i}", 0) == [(1000, 1032)]
        assert rows(shared, f"d2h{i}", 0) == [(1000, 1048)]
    fits = simulate(sort_first(h100_like(3.0)))  # 3 x 1 B/ns fits a 3 B/ns host side
    assert fits.trace.equals(plain.trace)
    # 3 GPUs: two copy their strips at once, at 1 B/ns each: they fit a 2 B/ns host side
    three = simulate(sort_first(h100_like(2.0), gpus=3))
    assert rows(three, "d2h1", 0) + rows(three, "d2h2", 0) == [(1000, 1032), (1000, 1064)]  # 32 / 64 B
    assert three.trace.equals(simulate(sort_first(h100_like(None), gpus=3)).trace)


def test_needed_only_where_two_gpus_cross_a_direction_with_a_host_capacity():
    for pcie, gpus, needed in ((None, 4, False), (2.0, 4, True), (2.0, 2, False)):
        exp = sort_first(h100_like(pcie), gpus)
        assert ("host_pcie" in choose_effects(build_program(exp), exp.profile)) == needed, (pcie, gpus)
        assert "host_pcie" not in choose_effects(build_program(exp), exp.profile, "queues")
    assert "host_pcie" in EFFECTS


def test_forced_off_gives_each_link_its_own():
    plain = simulate(sort_first(h100_like(None)))
    off = simulate(sort_first(h100_like(2.0)), effects={"host_pcie": False})
    assert off.trace.equals(plain.trace)


def test_a_bad_capacity_is_an_input_error_naming_the_key():
    with pytest.raises(InputError, match="pcie_d2h_gbps"):
        h100_like(-1.0)


def test_the_calibration_sums_the_rates_of_the_gpus_copying_at_once():
    import pandas as pd

    from mgpusim.calibration.recipe import _host_pcie
    rows = [("copy_d2h", 1, "gpu0", "graphics", 1000, 10)]  # alone: not the host side
    for name, ns in (("gpu0", 40), ("gpu1", 50)):  # 2 GPUs at once, the largest size counts
        rows += [("copy_d2h", 2, name, "graphics", 1000, ns), ("copy_d2h", 2, name, "transfer", 1000, ns * 2),
                 ("copy_d2h", 2, name, "graphics", 100, 1)]
    df = pd.DataFrame(rows, columns=["pass", "gpus", "gpu", "queue", "bytes", "duration_ns"])
    data: dict = {"host": {}}
    line = _host_pcie(data, df)
    assert data["host"] == {"pcie_d2h_gbps": 45.0}  # 1000/40 + 1000/50 B/ns
    assert "2 GPUs copying at once" in line and "host_pcie" in data["sources"]
    assert "unset" in _host_pcie({"host": {}}, df[df.gpus == 1])


def test_the_fast_forward_keeps_the_shared_host_side_exact():
    exp = experiment(h100_like(2.0), "sort_first", [timed("fragment_loop", 1000)], gpus=4, frames=200,
                     width=8, height=4, warmup=0)
    fast, slow = simulate(exp, fast_forward=True), simulate(exp, fast_forward=False)
    assert fast.summary["fast_forward"]["used"] and "host_pcie" in fast.summary["modelled_effects"]
    assert fast.trace.equals(slow.trace)
