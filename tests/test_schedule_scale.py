"""A pass kind's factor per schedule: parsed and checked, applied only to that schedule's frames,
and measured by the calibration on each schedule's own runs (the model as ground truth)."""
from __future__ import annotations

import copy

import pytest

from mgpusim import simulate
from mgpusim.calibrate.runs import fit_schedule_scales, with_schedule_scales
from mgpusim.costs import CostModel
from mgpusim.errors import InputError
from mgpusim.profile import parse_profile
from tests.conftest import make_experiment, profile_dict


def scaled(factors: dict) -> dict:
    prof = profile_dict(gpus=2)
    prof["gpus"][0]["costs"]["mesh"] = {"fixed_ns": 200.0, "ns_per_pixel": 0.0,
                                        "ns_per_triangle": 3.0, "schedule_scale": factors}
    return prof


def run(prof: dict, schedule: str, triangles: int):
    extra = {"views": 2, "mode": "simulated"} if schedule == "xr" else {}
    exp = make_experiment(copy.deepcopy(prof), schedule=schedule, gpus=1, width=16, height=8,
                          iterations=triangles, frames=10, **extra)
    return exp, simulate(exp).trace


def render_ns(trace, task: str) -> int:
    return int((trace["end_ns"] - trace["start_ns"])[trace["task"] == task].iloc[-1])


def test_the_factor_applies_to_its_schedule_only():
    prof = parse_profile(scaled({"xr": 1.5}), "p.toml")
    work = {"triangle": 100.0, "pixel": 0.0}
    assert CostModel(prof, "xr").pass_ns(0, "mesh", work) == 750  # (200 + 300) x 1.5
    assert CostModel(prof, "sort_last").pass_ns(0, "mesh", work) == 500
    assert CostModel(prof).pass_ns(0, "mesh", work) == 500
    _, xr = run(scaled({"xr": 1.5}), "xr", 100)
    _, sl = run(scaled({"xr": 1.5}), "sort_last", 100)
    assert render_ns(xr, "render0.p") == 750
    assert render_ns(sl, "render0") == 500


@pytest.mark.parametrize("factors, message", [
    ({"xrr": 1.1}, "unknown schedule (did you mean 'xr'?)"),
    ({"xr": 0.0}, "schedule_scale.xr"),
    ({"xr": 11.0}, "schedule_scale.xr"),
    ({"xr": "fast"}, "schedule_scale.xr"),
])
def test_a_bad_factor_is_refused_with_its_field(factors, message):
    with pytest.raises(InputError) as err:
        parse_profile(scaled(factors), "p.toml")
    assert message in str(err.value)


def test_calibration_measures_each_schedules_factor_on_its_own_runs():
    """Runs made with XR's meshes 1.25x dearer than sort-last's: fitted on a profile without
    factors, sort-last's come out 1.0 and XR's 1.25, and the profile with them reproduces the
    runs' renders."""
    truth = scaled({"xr": 1.25})
    runs = [run(truth, "sort_last", n) for n in (100, 400)] + [run(truth, "xr", 300)]
    plain = scaled({})
    del plain["gpus"][0]["costs"]["mesh"]["schedule_scale"]
    found = fit_schedule_scales(runs, plain, ["mesh"], gpus=1)
    assert set(found) == {"mesh"}
    assert found["mesh"]["sort_last"][0] == pytest.approx(1.0, abs=0.01)
    assert found["mesh"]["xr"][0] == pytest.approx(1.25, abs=0.01)
    assert found["mesh"]["xr"][1] >= 2 * 8  # two views, each steady frame
    fitted = with_schedule_scales(plain, found)
    _, xr = run(fitted, "xr", 300)
    assert render_ns(xr, "render1.p") == render_ns(runs[2][1], "render1.p")


def test_a_kind_only_one_schedule_has_gets_no_factor():
    """With one schedule's runs there is nothing to tell its frame from the fit's."""
    truth = scaled({"sort_last": 1.3})
    runs = [run(truth, "sort_last", n) for n in (100, 400)]
    assert fit_schedule_scales(runs, scaled({}), ["mesh"], gpus=1) == {}
