"""The fluid link model: exact integer-ns answers for hand-computable cases, and laws."""
from __future__ import annotations

from fractions import Fraction

import simpy
from hypothesis import given, settings, strategies as st

from mgpusim.costs import round_half_up
from mgpusim.sim.channel import Channel


def run_flows(bandwidth: Fraction, flows: list[tuple[int, int, Fraction | None]]) -> list[int]:
    """Start each (start_ns, bytes, cap) flow; return each one's finish time."""
    env = simpy.Environment()
    ch = Channel(env, "link", bandwidth)
    ends: list[int] = [0] * len(flows)

    def one(i: int, start: int, nbytes: int, cap):
        yield env.timeout(start)
        yield ch.transfer(nbytes, cap)
        ends[i] = env.now

    for i, (start, nbytes, cap) in enumerate(flows):
        env.process(one(i, start, nbytes, cap))
    env.run()
    return ends


def test_single_transfer_takes_rounded_bytes_over_bandwidth():
    w = Fraction(3)  # 3 bytes per ns
    assert run_flows(w, [(0, 1000, None)]) == [round_half_up(Fraction(1000, 3))]  # 333
    assert run_flows(w, [(0, 1001, None)]) == [334]  # 333.67 rounds up
    assert run_flows(w, [(7, 1000, None)]) == [7 + 333]


def test_two_equal_concurrent_transfers_each_take_twice_as_long():
    assert run_flows(Fraction(2), [(0, 1000, None), (0, 1000, None)]) == [1000, 1000]


def test_transfer_joining_later_finishes_where_fluid_model_says():
    # A: 1000 B from t=0 at 1 B/ns alone until t=400 (600 left); then both at 0.5 B/ns.
    # B: 300 B from t=400 -> done at 400 + 600 = 1000. A then has 600-300 = 300 left at 1 B/ns.
    assert run_flows(Fraction(1), [(0, 1000, None), (400, 300, None)]) == [1300, 1000]


def test_caps_share_max_min_fair():
    # Capped flow gets 0.25, the other takes the rest (0.75) of 1 B/ns.
    assert run_flows(Fraction(1), [(0, 250, Fraction(1, 4)), (0, 750, None)]) == [1000, 1000]


def test_zero_bytes_and_extreme_ratios():
    assert run_flows(Fraction(1), [(5, 0, None)]) == [5]
    tb = 10**12
    ends = run_flows(Fraction(10), [(0, 1, None), (0, tb, None)])
    assert ends[0] == 0  # 1 byte at 5 B/ns is 0.2 ns: rounds to 0
    assert ends[1] == tb // 10  # the tiny flow's share is not lost


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5000), st.integers(0, 10**6)), min_size=1, max_size=6),
       st.integers(1, 50))
def test_work_conservation_bounds(flows, bw):
    """No flow beats the link alone, and the last finish equals total bytes / bandwidth
    when the link never idles (all start at once), within the per-completion rounding."""
    ends = run_flows(Fraction(bw), [(s, b, None) for s, b in flows])
    for (s, b), e in zip(flows, ends):
        assert e >= s + round_half_up(Fraction(b, bw)) - 1
    same_start = run_flows(Fraction(bw), [(0, b, None) for _, b in flows])
    total = sum(b for _, b in flows)
    assert abs(max(same_start) - Fraction(total, bw)) <= len(flows)
