"""simulate() reuses what it derives from an experiment, and its shortcuts give what the
plain computations give: the busy time of a repeated block in closed form, and the analytic
level's own per-frame arrays for a run with a repeat."""
from __future__ import annotations

import gc
import random
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mgpusim.results.periodic import shifted_overlap, shifted_overlaps
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim import prepared
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]


def test_shifted_overlaps_matches_one_by_one() -> None:
    rng = random.Random(7)
    for _ in range(3000):
        t = rng.choice([1, 3, 10, 997])
        copies = rng.choice([0, 1, 4, 50, 10_000])
        n = rng.choice([1, 5, 40, 80])
        s = [rng.randint(-3 * t, 40 * t) for _ in range(n)]
        e = [a + rng.randint(0, t) for a in s]
        lo = rng.randint(-5 * t, 60 * t)
        hi = lo + rng.randint(0, rng.choice([t, 7 * t, 300 * t, 50_000 * t]))
        got = shifted_overlaps(np.array(s, dtype=np.int64), np.array(e, dtype=np.int64), t, copies, lo, hi)
        assert got.tolist() == [shifted_overlap(a, b, t, copies, lo, hi) for a, b in zip(s, e)]


def test_longer_than_the_step_falls_back() -> None:
    s = np.array([0] * 40, dtype=np.int64)
    e = np.arange(40, dtype=np.int64) * 5
    got = shifted_overlaps(s, e, 3, 20, 4, 50)
    assert got.tolist() == [shifted_overlap(0, b, 3, 20, 4, 50) for b in e.tolist()]


@pytest.mark.parametrize("name", ["afr_tc1.toml", "h100_x4/afr_temporal.toml", "lavapipe/particles.toml"])
def test_analytic_frames_match_the_rows(name: str) -> None:
    """A run with a repeat: its per-frame starts and presents (the recurrence's own arrays,
    extended) are those its compact rows give."""
    exp = load_experiment(ROOT / "experiments" / name, {"schedule.frames": 120})
    result = simulate(exp, fidelity="analytic")
    assert result.summary["fast_forward"]["used"] and result.compact
    start, present = result.repeated.frame_arrays(120, build_program(exp).present_task)
    assert result.frames["start_ns"].tolist() == start.tolist()
    assert result.frames["present_ns"].tolist() == present.tolist()


def test_repeated_calls_give_the_same_result_and_reuse_the_program() -> None:
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml")
    first = simulate(exp, fidelity="analytic")
    program = prepared.cached(exp, "program", lambda: None)
    assert program is not None  # kept by the first call
    again = simulate(exp, fidelity="analytic")
    assert again.summary == first.summary
    assert again.trace.equals(first.trace)
    other = replace(exp, schedule=replace(exp.schedule, frames=exp.schedule.frames + 1))
    assert simulate(other, fidelity="analytic").summary["frames"] == exp.schedule.frames + 1


def test_an_entry_goes_with_its_experiment() -> None:
    # a copy of its own: load_experiment keeps the experiment it loaded while the file is unchanged
    exp = replace(load_experiment(ROOT / "experiments" / "afr_tc1.toml"), name="afr_tc1 copy")
    simulate(exp, fidelity="analytic")
    key = id(exp)
    assert key in prepared._STORE
    del exp
    gc.collect()
    assert key not in prepared._STORE
