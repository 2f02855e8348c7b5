"""Experiments that share a profile object (a sweep's points) share one recording copy of it
for simulate()'s unused-override check (mgpusim/sim/simulation.py, `_watched`), each noting
its own reads: each point's summary and error are those of simulate() on the point's own
experiment, a point whose override its run does not read included."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from mgpusim import load_experiment, simulate
from mgpusim.model.errors import MgpusimError
from mgpusim.sim import simulation
from mgpusim.sweeps import grid as sweeps

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "sort_first_tc1.toml"
#: without host copies the memcpy threads' rate is read by nothing: those points fail
GRID = {"schedule.host_copy": [True, False], "profile.host.memcpy_thread_gbps": [5, 9],
        "profile.gpus.*.speed": [1, 2]}


def _own(overrides: dict, fidelity: str) -> tuple[str, str | None]:
    try:
        summary = simulate(load_experiment(EXPERIMENT, overrides), fidelity=fidelity).summary
    except MgpusimError as exc:
        return "", str(exc)
    return json.dumps(sweeps.flatten(summary), sort_keys=True, default=str), None


@pytest.mark.parametrize("fidelity", ["full", "analytic"])
def test_points_on_a_shared_copy_give_their_own_results_and_errors(fidelity):
    points = [{**dict(zip(GRID, values)), "schedule.frames": 40} for values in itertools.product(*GRID.values())]
    sweeps.loader(EXPERIMENT)  # (the points' loader: one profile object per set of profile overrides)
    got = [sweeps.run_point(str(EXPERIMENT), p, {"fidelity": fidelity}) for p in points]
    shared = sweeps.loader(EXPERIMENT)
    one, two = (shared.load(dict(p)) for p in (points[0], points[4]))  # same profile overrides, other host_copy
    assert one is not two and one.profile is two.profile
    watched = [simulation._watched(e, fidelity, None) for e in (one, two)]
    assert watched[0][0].profile is watched[1][0].profile  # one copy per profile, shared
    assert watched[0][1] is not watched[1][1]  # each experiment its own reads
    for point, record in zip(points, got):
        summary, error = _own(point, fidelity)
        assert record["error"] == error
        if error is None:
            assert json.dumps(record["summary"], sort_keys=True, default=str) == summary
    failed = [p for p, r in zip(points, got) if r["error"]]
    assert failed and all(not p["schedule.host_copy"] for p in failed)
    assert all("memcpy_thread_gbps" in r["error"] for r in got if r["error"])
