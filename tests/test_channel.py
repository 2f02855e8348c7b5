"""The fluid link model: exact integer-ns answers for hand-computable cases, and laws."""
from __future__ import annotations

from fractions import Fraction

import simpy
from hypothesis import given, settings
from hypothesis import strategies as st

from mgpusim.model.costs import round_half_up
from mgpusim.sim.channel import Channel, PassWork


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


def run_core_flows(tags: list[object], caps: list[Fraction], work: int = 3200) -> list[int]:
    """Flows of `work` at `caps` cores on 2 cores that deliver 1.6 at twice the demand."""
    env = simpy.Environment()
    ch = Channel(env, "host.cpu", Fraction(2), Fraction(8, 5))
    ends: list[int] = [0] * len(tags)

    def one(i: int):
        yield ch.transfer(work, caps[i], tags[i])
        ends[i] = env.now

    for i in range(len(tags)):
        env.process(one(i))
    env.run()
    return ends


def test_different_work_on_oversubscribed_cores_loses_what_the_efficiency_says():
    """Two kinds of pass at 2 cores each on 2 cores (twice the demand): the cores deliver 1.6,
    0.8 each, so 3200 core-ns take 4000 ns; a copy (untagged) beside a pass loses the same."""
    two = [Fraction(2), Fraction(2)]
    assert run_core_flows([PassWork("fragment_loop"), PassWork("filter")], two) == [4000, 4000]
    assert run_core_flows([PassWork("fragment_loop"), None], two) == [4000, 4000]


def test_passes_of_one_kind_lose_nothing_when_they_oversubscribe_the_cores():
    two = [Fraction(2), Fraction(2)]
    assert run_core_flows([PassWork("fragment_loop")] * 2, two) == [3200, 3200]
    assert run_core_flows([None, None], two) == [4000, 4000]  # untagged work always mixes


def test_a_lossless_kind_takes_no_part_in_the_loss_beside_other_work():
    """A mesh whose cores were measured two at once (lossless) beside a filter: only the
    filter's half of the demand loses, 2 - 0.4 / 2 = 1.8 cores, 0.9 each: 3200 / 0.9 = 3556."""
    two = [Fraction(2), Fraction(2)]
    assert run_core_flows([PassWork("mesh", lossless=True), PassWork("filter")], two) == [3556, 3556]


def test_slight_oversubscription_by_different_work_loses_little():
    """1.5 cores each, 3 wanted of 2, half-way to twice the cores: half the loss, 1.8 cores,
    0.9 each; 2400 core-ns take 2400 / 0.9 = 2667 ns."""
    caps = [Fraction(3, 2), Fraction(3, 2)]
    assert run_core_flows([PassWork("fragment_loop"), PassWork("filter")], caps, 2400) == [2667, 2667]


def test_occupants_share_the_channel_and_leave_nothing_behind():
    """An occupant (measured work replayed) takes its fair share until released: a transfer
    beside two 2-core occupants on 2 cores gets a third, and one that starts in the nanosecond
    both leave takes its full time (a pending settle of the emptied channel once ended it at
    once)."""
    env = simpy.Environment()
    ch = Channel(env, "cpu", Fraction(2))
    ends: list[tuple[int, int]] = []

    def occupant():
        held = ch.occupy(Fraction(2))
        yield env.timeout(1000)
        ch.release(held)

    def work(at: int, ns: int):
        yield env.timeout(at)
        start = env.now
        yield ch.transfer(ns, Fraction(1))
        ends.append((start, env.now))

    env.process(occupant())
    env.process(occupant())
    env.process(work(500, 100))
    env.process(work(1000, 100))
    env.run()
    assert ends == [(500, 650), (1000, 1100)]
    assert env.now == 1100  # no planned end of an occupant left in the queue


class _SolverOnly(Channel):
    """The channel with its fast path for several capped transfers turned off."""

    shares_caps_freely = False


def _ends_and_busy(kind: type, bandwidth: Fraction, flows: list[tuple[int, int, Fraction | None]]):
    env = simpy.Environment()
    ch = kind(env, "link", bandwidth)
    ends: list[int] = [0] * len(flows)

    def one(i: int, start: int, nbytes: int, cap):
        yield env.timeout(start)
        yield ch.transfer(nbytes, cap)
        ends[i] = env.now

    for i, (start, nbytes, cap) in enumerate(flows):
        env.process(one(i, start, nbytes, cap))
    env.run()
    return ends, ch.busy, ch.max_concurrent


@settings(max_examples=300, deadline=None)
@given(flows=st.lists(st.tuples(st.integers(0, 60), st.integers(1, 400),
                                st.sampled_from([None, Fraction(1), Fraction(3, 2), Fraction(2), Fraction(5, 3)])),
                      min_size=1, max_size=7),
       bw=st.sampled_from([Fraction(4), Fraction(7, 2), Fraction(10)]))
def test_capped_transfers_that_fit_take_the_fast_path_with_the_solvers_answers(flows, bw):
    """While the caps of the running transfers add up to no more than the bandwidth, each
    crosses at its cap without the solver; ends, busy intervals and the crowd are the solver's."""
    assert _ends_and_busy(Channel, bw, flows) == _ends_and_busy(_SolverOnly, bw, flows)


def test_three_capped_copies_that_fit_never_start_the_solver():
    env = simpy.Environment()
    ch = Channel(env, "host.memory", Fraction(30))
    for _ in range(3):
        ch.transfer(524288, Fraction(8))
    assert all(f.solo_rate == 8 for f in ch.flows) and len(ch.flows) == 3
    ch.transfer(524288, Fraction(8))  # 32 > 30: the solver takes every flow over
    assert not any(f.solo_rate for f in ch.flows)
    env.run()
    assert ch.busy and ch.max_concurrent == 4


def _reference_rates(ch: Channel) -> list[int]:
    """Water-filling as written plainly (the order of the scaled caps, uncapped last, equal
    ones as they came; each at the fair split of what is left or its cap if lower): what the
    solver's written-out cases for one and two flows must give."""
    left = ch._left_now()
    order = sorted(range(len(ch.flows)), key=lambda i: (ch.flows[i].cap is None, ch.flows[i].cap or 0))
    rates = [0] * len(order)
    for k, i in enumerate(order):
        cap_s = ch.flows[i].cap_s
        fair = left // (len(order) - k)
        rates[i] = fair if cap_s is None or cap_s >= fair else cap_s
        left -= rates[i]
    return rates


@settings(max_examples=300, deadline=None)
@given(flows=st.lists(st.tuples(st.integers(1, 10 ** 6),
                                st.sampled_from([None, Fraction(1), Fraction(3, 2), Fraction(2),
                                                 Fraction(5, 3), Fraction(7, 3)])), min_size=2, max_size=6),
       bw=st.sampled_from([Fraction(3), Fraction(7, 2), Fraction(10)]),
       over=st.sampled_from([None, Fraction(5, 2)]))
def test_shares_are_water_filling_for_every_crowd(flows, bw, over):
    """The solver's shares (after every settle, as flows end one by one: three, two, one;
    capped, uncapped, equal caps; on oversubscribed cores too) are plain water-filling's,
    exactly."""
    env = simpy.Environment()
    ch = Channel(env, "host.cpu", bw, over if over is not None and over < bw else None)
    for nbytes, cap in flows:
        ch.transfer(nbytes, cap, PassWork("x") if cap == Fraction(2) else None)
    while env.peek() != simpy.core.Infinity:
        env.step()
        if ch.flows and not ch._settle_pending and ch.flows[0].solo_rate == 0:
            assert [f.rate for f in ch.flows] == _reference_rates(ch)
            assert sum(f.rate for f in ch.flows) <= ch._left_now()
