"""`mgpusim bench` compares like with like: its hand-written SimPy model of the sort-first frame
computes the model's own presents, frame after frame."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.bench.model_speed import events_per_frame, sort_first_experiment
from mgpusim.bench.reference import hand_written_sort_first
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
SORT_FIRST = ROOT / "experiments" / "sort_first_tc1.toml"


@pytest.mark.parametrize("gpus", [2, 3, 4])
def test_the_hand_written_model_reproduces_the_models_presents(gpus: int):
    exp = sort_first_experiment(SORT_FIRST, gpus, 400)
    model = simulate(exp, record_trace=False, fast_forward=False).frames["present_ns"].tolist()
    assert hand_written_sort_first(exp) == model


def test_the_hand_written_model_at_the_shipped_length():
    exp = load_experiment(SORT_FIRST)
    assert hand_written_sort_first(exp) == simulate(exp).frames["present_ns"].tolist()


def test_the_hand_written_model_says_when_host_memory_would_bind():
    exp = load_experiment(SORT_FIRST, {"profile.host.memory_bandwidth_gbps": 9.0, "schedule.frames": 12})
    with pytest.raises(AssertionError, match="host memory binds"):
        hand_written_sort_first(exp)


def test_events_are_counted_for_both_models():
    counts = events_per_frame(sort_first_experiment(SORT_FIRST, 2, 100), 100)
    assert 10 < counts["model"] < counts["hand_written"] < 60
