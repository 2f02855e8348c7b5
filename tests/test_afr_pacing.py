"""AFR's even pacing (`schedule.pace_us`): the engine holds each present to an even cadence.
Exact integer-ns timelines at every fidelity level, a cadence the GPUs hold and one they
cannot, and the pacer marked simulated only."""
from __future__ import annotations

import pytest

from mgpusim import simulate
from mgpusim.schedules.program import build_program
from tests.schedule_helpers import experiment, presents, profile, rows, timed


@pytest.mark.parametrize("fidelity", ["analytic", "queues", "full"])
def test_paced_afr_presents_at_an_even_cadence_exact_timeline(fidelity):
    """1000 ns frames on two GPUs. Unpaced, GPU 0's frames present at 1010, 2020, ... and GPU 1's
    64 ns later (its image crosses, 32 + 32 ns): bursts 64 ns apart, then ~950 ns gaps. Paced
    at 600 ns, frame f's hold (the pacer's release) is max(its image is ready, the previous
    hold + 600): 1000, 1600, 2200, ...; each present (10 ns) follows its hold, so presents come
    exactly 600 ns apart and each GPU starts its next frame at its previous present."""
    plain = simulate(experiment(profile(), "afr", [timed("a", 1000)], frames=8), fidelity=fidelity)
    assert presents(plain) == [1010, 1074, 2020, 2148, 3030, 3222, 4040, 4296]
    r = simulate(experiment(profile(), "afr", [timed("a", 1000)], frames=8, pace_us=0.6), fidelity=fidelity)
    assert presents(r) == [1010 + 600 * k for k in range(8)]
    if fidelity == "analytic":
        return
    assert rows(r, "render.a") == [(0, 1000), (0, 1000), (1010, 2010), (1610, 2610), (2210, 3210),
                                   (2810, 3810), (3410, 4410), (4010, 5010)]
    assert rows(r, "pace.hold") == [(1000 + 600 * k, 1000 + 600 * k) for k in range(8)]
    assert rows(r, "pace.gap") == [(1000 + 600 * k, 1600 + 600 * k) for k in range(8)]
    assert rows(r, "present") == [(1000 + 600 * k, 1010 + 600 * k) for k in range(8)]
    assert set(r.trace[r.trace.step == "pace"].engine) == {"pacer"}
    # the frame starts at its first render, not at the pacer's timer: latency is the frame's
    assert list(r.frames.latency_ns[2:]) == [1200] * 6


def test_a_cadence_the_gpus_can_hold_is_exactly_even_and_a_faster_one_is_not():
    """GPU 1's cycle is 1074 ns for two frames (render 1000, its image 64, present 10): a
    537 ns cadence holds exactly; at 500 ns the GPUs cannot keep up and the presents come as
    they are ready, 500 and 574 ns apart."""
    def periods(pace: float) -> set[int]:
        r = simulate(experiment(profile(), "afr", [timed("a", 1000)], frames=40, pace_us=pace))
        p = presents(r)
        return {b - a for a, b in zip(p[20:], p[21:])}
    assert periods(0.537) == {537}
    assert periods(0.5) == {500, 574}


def test_pacing_is_simulated_only_and_off_by_default():
    paced = build_program(experiment(profile(), "afr", [timed("a", 1000)], pace_us=0.6))
    pacer = [t for t in paced.templates[0] if t.name.startswith("pace.")]
    assert [t.name for t in pacer] == ["pace.hold", "pace.gap"]
    assert all("unsupported" in t.params and "simulated only" in t.params["unsupported"] for t in pacer)
    plain = build_program(experiment(profile(), "afr", [timed("a", 1000)]))
    assert not any(t.name.startswith("pace.") for tasks in plain.templates for t in tasks)
