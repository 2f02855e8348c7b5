"""Resident data per GPU: overflow is reported before running; largest data set query."""
from __future__ import annotations

import pytest

from mgpusim import InputError, simulate
from mgpusim.schedules.memory_check import footprints, max_dataset_bytes
from mgpusim.schedules.program import build_program
from tests.schedule_helpers import experiment, gpu, profile, timed

MESH = [{"name": "m", "kind": "mesh", "triangles": 10}]


def sort_last(n: int, dataset: int, memory: int = 1000):
    """8x4 frame: colour 128 B, depth 64 B (192 B per full target)."""
    return experiment(profile([gpu(count=3, memory=memory)]), "sort_last", MESH, gpus=n, width=8,
                      height=4, dataset=dataset, frames=4)


def test_one_gpu_fits_exactly_then_overflows_by_one_byte():
    # GPU 0: data set + its target (192) + the presented colour image (128) = D + 320
    simulate(sort_last(1, 680))
    with pytest.raises(InputError) as err:
        simulate(sort_last(1, 681))
    msg = str(err.value)
    assert "gpu0" in msg and "overflows by 1 bytes" in msg and "scene.dataset_bytes" in msg


def test_overflow_names_the_gpu_that_overflows():
    # sort-last on 2: GPU 0 also holds 2 x 192 B of received contributions
    exp = sort_last(2, 1000)
    with pytest.raises(InputError, match=r"gpu0 .* overflows by 204 bytes"):
        simulate(exp)


def test_largest_data_set_sort_last_vs_one_gpu():
    one = max_dataset_bytes(sort_last(1, 0, memory=10_000))
    two = max_dataset_bytes(sort_last(2, 0, memory=10_000))
    three = max_dataset_bytes(sort_last(3, 0, memory=10_000))
    assert one == 10_000 - 320
    assert two == 2 * (10_000 - 320 - 2 * 192)  # GPU 0 holds half plus two received targets
    assert three > two > one
    simulate(sort_last(2, two, memory=10_000))
    with pytest.raises(InputError):
        simulate(sort_last(2, two + 2, memory=10_000))


def test_sort_first_cannot_hold_more_than_one_gpu():
    def exp(n: int):
        return experiment(profile([gpu(count=2, memory=10_000)]), "sort_first",
                          [{"name": "f", "kind": "fragment_loop", "iterations": 1}],
                          gpus=n, width=8, height=4, frames=4)
    assert max_dataset_bytes(exp(2)) <= max_dataset_bytes(exp(1))


def test_summary_reports_memory_use():
    r = simulate(sort_last(2, 100, memory=10_000))
    assert r.summary["memory"]["gpu1"] == {"used_bytes": 50 + 2 * 192, "capacity_bytes": 10_000,
                                           "fraction": round((50 + 384) / 10_000, 6)}


def test_every_schedule_has_a_footprint_rule():
    prof = profile([gpu(count=2)])
    cases = [("afr", [timed("a", 10)], {}), ("pipelining", [timed("a", 10, output_bytes=64), timed("b", 10)], {}),
             ("xr", [timed("v", 10)], {"cbpp": 3, "dbpp": 3}), ("particles", [timed("geometry", 10)], {})]
    for name, passes, kw in cases:
        fps = footprints(build_program(experiment(prof, name, passes, frames=4, **kw)), experiment(prof, name, passes, frames=4, **kw).scene)
        assert len(fps) == 2 and all(f.targets >= 0 and f.staging >= 0 for f in fps)
