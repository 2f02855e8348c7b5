"""Sort-first tiles per GPU: given heights, and heights balanced from the GPUs' costs."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim import InputError, load_experiment, simulate
from mgpusim.schedules.five_step import balanced_rows
from tests.schedule_helpers import COSTS, experiment, gpu, profile

LOOP = [{"name": "f", "kind": "fragment_loop", "iterations": 1}]
ROOT = Path(__file__).resolve().parents[1]


def hetero():
    """GPU 1 is 3x slower per pixel; compositing is free, present costs 10 ns."""
    slow = dict(COSTS, fragment_loop={"ns_per_pixel": 0.0, "ns_per_pixel_iteration": 3.0})
    return profile([gpu(), gpu(costs=slow)])


def test_given_tile_rows_are_used():
    r = simulate(experiment(hetero(), "sort_first", LOOP, width=1, height=40, frames=4, tile_rows=[30, 10]))
    assert r.config["tile_rows"] == (30, 10)
    d2h = r.trace[r.trace.step == "d2h"]
    assert set(d2h.bytes) == {10 * 4}


@pytest.mark.parametrize("bad", [[30, 9], [40], [41, -1], [20.5, 19.5]])
def test_bad_tile_rows_rejected(bad):
    with pytest.raises(InputError, match="tile_rows"):
        simulate(experiment(hetero(), "sort_first", LOOP, width=1, height=40, frames=4, tile_rows=bad))


def test_balance_by_hand():
    """GPU 0 carries r0 + 10 ns, GPU 1 3 x r1 ns, r0 + r1 = 40: r0 = 28 gives max(38, 36)."""
    exp = experiment(hetero(), "sort_first", LOOP, width=1, height=40, frames=4, balance=True)
    assert balanced_rows(exp.scene, exp.profile, 2) == [28, 12]
    assert simulate(exp).config["tile_rows"] == (28, 12)


def test_balance_beats_equal_tiles_on_heterogeneous_gpus():
    kw = dict(width=1, height=40, frames=30, warmup=5)
    equal = simulate(experiment(hetero(), "sort_first", LOOP, **kw))
    balanced = simulate(experiment(hetero(), "sort_first", LOOP, balance=True, **kw))
    assert balanced.summary["frame_time_ms"] < equal.summary["frame_time_ms"]


def test_balance_on_tc2_is_never_worse():
    path = ROOT / "experiments" / "sort_first_tc1.toml"
    prof = ROOT / "hardware_profiles" / "tc2.toml"
    equal = simulate(load_experiment(path, profile=prof))
    balanced = simulate(load_experiment(path, {"schedule.balance": True}, profile=prof))
    assert balanced.summary["frame_time_ms"] <= equal.summary["frame_time_ms"]
    assert sum(balanced.config["tile_rows"]) == 768


def test_gpus_alike_are_balanced_once_and_as_each_alone(monkeypatch):
    """GPUs of one profile share their loads in the bisections (the first of them stands for
    the rest); the heights are those of the search over every GPU on its own."""
    from mgpusim.schedules import five_step
    slow = dict(COSTS, fragment_loop={"ns_per_pixel": 0.0, "ns_per_pixel_iteration": 3.0})
    mixed = profile([gpu(), gpu(costs=slow), gpu(), gpu(costs=slow), gpu()])
    assert five_step._alike_gpus(mixed, 5) == [0, 1, 2, 1, 2]
    exp = experiment(mixed, "sort_first", LOOP, width=3, height=97, frames=4, balance=True)
    shared = balanced_rows(exp.scene, exp.profile, 5)
    monkeypatch.setattr(five_step, "_alike_gpus", lambda _profile, n: list(range(n)))
    assert balanced_rows(exp.scene, exp.profile, 5) == shared
