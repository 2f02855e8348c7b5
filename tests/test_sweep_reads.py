"""A sweep's points share one recording copy per profile for simulate()'s unused-override
check (mgpusim/sweeps/reads.py): each point's summary and error are those of simulate() on
the point's own experiment, a point whose override its run does not read included."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from mgpusim import load_experiment, simulate
from mgpusim.model.errors import MgpusimError
from mgpusim.sweeps import grid as sweeps
from mgpusim.sweeps import reads

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
    assert len({id(e[0]) for e in reads._COPIES.values()}) >= 4  # one copy per profile, shared
    for point, record in zip(points, got):
        summary, error = _own(point, fidelity)
        assert record["error"] == error
        if error is None:
            assert json.dumps(record["summary"], sort_keys=True, default=str) == summary
    failed = [p for p, r in zip(points, got) if r["error"]]
    assert failed and all(not p["schedule.host_copy"] for p in failed)
    assert all("memcpy_thread_gbps" in r["error"] for r in got if r["error"])
