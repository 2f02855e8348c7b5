"""Calibration from runs recovers what generated the runs (the model as ground truth)."""
from __future__ import annotations

import copy

import pytest

from mgpusim import simulate
from mgpusim.calibration.run_fit import fit_host_effects, fit_passes_from_runs, fit_task_gap
from tests.conftest import make_experiment, profile_dict


def truth() -> dict:
    prof = profile_dict(gpus=2)
    prof["host"].update(cpu_cores=2, gpus_share_cpu=True, dispatch_ns=400, oversubscribed_efficiency=0.8)
    prof["gpus"][0]["task_gap_ns"] = 30
    prof["gpus"][0]["costs"]["fragment_loop"] = {"fixed_ns": 500.0, "ns_per_pixel": 2.0,
                                                 "ns_per_pixel_iteration": 0.5}
    return prof


def runs(prof: dict, configs) -> list:
    out = []
    for gpus, w, h, it in configs:
        exp = make_experiment(copy.deepcopy(prof), gpus=gpus, width=w, height=h, iterations=it, frames=12)
        out.append((exp, simulate(exp).trace))
    return out


def test_pass_costs_and_queue_gap_from_single_gpu_runs():
    single = runs(truth(), [(1, 16, 8, 10), (1, 32, 16, 40), (1, 64, 8, 5), (1, 8, 8, 100)])
    fit = fit_passes_from_runs(single)["fragment_loop"]
    got = dict(zip(fit.names, fit.coef))
    assert got["ns_per_pixel_iteration"] == pytest.approx(0.5, rel=0.02)
    assert got["ns_per_pixel"] == pytest.approx(2.0, rel=0.1)
    assert got["fixed_ns"] == pytest.approx(500, abs=60)  # durations are rounded to the ns
    assert fit_task_gap(single) == 30


def test_host_effects_from_multi_gpu_runs():
    prof = truth()
    multi = runs(prof, [(2, 32, 16, 40), (2, 16, 16, 10)])
    start = copy.deepcopy(prof)
    start["host"].update(dispatch_ns=0, oversubscribed_efficiency=1.0)
    found, score = fit_host_effects(start, multi, {"dispatch_ns": (0, 200, 400, 800),
                                                   "oversubscribed_efficiency": (1.0, 0.9, 0.8, 0.7)})
    assert found == {"dispatch_ns": 400, "oversubscribed_efficiency": 0.8}
    assert score == pytest.approx(0.0, abs=1e-9)


def test_host_grid_gives_the_same_answer_on_one_process_and_on_several(monkeypatch):
    """The trials are shared among forked workers; the winner (the first of the lowest error)
    and its score do not depend on how many."""
    prof = truth()
    multi = runs(prof, [(2, 32, 16, 40), (1, 16, 16, 10)])
    grid = {"dispatch_ns": (0, 100, 200, 300, 400, 600, 800), "submit_ns": (0, 50, 100)}
    monkeypatch.delenv("MGPUSIM_WORKERS", raising=False)
    monkeypatch.setattr("os.sched_getaffinity", lambda _pid: {0, 1, 2}, raising=False)
    several = fit_host_effects(copy.deepcopy(prof), multi, grid)
    monkeypatch.setattr("os.sched_getaffinity", lambda _pid: {0}, raising=False)
    one = fit_host_effects(copy.deepcopy(prof), multi, grid)
    assert several == one



def test_refit_keeps_the_placed_terms_in_proportion():
    """Whole-frame runs cannot tell a mesh's placed terms apart: the refit keeps the
    microbenchmarks' per-term coefficients in proportion and fits a fixed cost and one scale;
    placed_shapes picks the kinds whose table fit has placed terms."""
    from mgpusim.calibration.recipe import placed_shapes
    from mgpusim.calibration.run_fit import _fit_scale
    shape = {"triangle": 40.0, "visible_triangle": 50.0, "triangle_edge": 45.0, "pixel": 0.5}
    samples = []
    for tri, edge, px in ((5000, 9000, 12288), (20000, 19000, 49152), (40000, 30000, 76800)):
        work = {"triangle": tri, "visible_triangle": tri, "triangle_edge": edge, "pixel": px}
        samples.append((work, 60_000 + 1.2 * sum(shape[t] * v for t, v in work.items())))
    fit = _fit_scale(samples, shape, "mesh")
    got = dict(zip(fit.names, fit.coef))
    assert got["fixed_ns"] == pytest.approx(60_000, rel=1e-6)
    for term, coef in shape.items():
        assert got[f"ns_per_{term}"] == pytest.approx(1.2 * coef, rel=1e-6)
    data = {"gpus": [{"costs": {"mesh": {"fixed_ns": 1.0, "ns_per_triangle": 2.0,
                                         "ns_per_visible_triangle": 3.0},
                                "fragment_loop": {"ns_per_pixel": 1.0}}}]}
    assert placed_shapes(data) == {"mesh": {"triangle": 2.0, "visible_triangle": 3.0}}
    data["gpus"][0]["costs"]["mesh"]["ns_per_visible_triangle"] = 0.0
    assert placed_shapes(data) == {}


def test_kinds_only_multi_gpu_runs_have_are_scaled_to_their_instances_alone():
    """A sort-last composite that costs twice per pixel what the microbenchmark fit says is
    found twice as costly (fixed cost kept), from the instances no other GPU's pass overlapped;
    1-GPU runs (no composite) give nothing to scale."""
    from mgpusim.calibration.run_fit import fit_alone_scales, with_alone_scales
    prof = profile_dict(gpus=3)
    prof["gpus"][0]["costs"]["composite_sort_last"] = {"fixed_ns": 100.0, "ns_per_pixel": 3.0,
                                                       "ns_per_input": 0.0}
    measured = []
    for gpus, w, h in ((2, 32, 16), (3, 16, 16), (1, 16, 16)):
        exp = make_experiment(copy.deepcopy(prof), schedule="sort_last", gpus=gpus, width=w,
                              height=h, iterations=200, frames=12)
        measured.append((exp, simulate(exp).trace))
    bench = {"composite_sort_last": {"fixed_ns": 100.0, "ns_per_pixel": 1.5, "ns_per_input": 0.0}}
    scales = fit_alone_scales(measured, ["composite_sort_last"], bench)
    scale, rows = scales["composite_sort_last"]
    assert scale == pytest.approx(2.0, rel=0.01)
    assert rows >= 10
    scaled = with_alone_scales({"gpus": [{"costs": copy.deepcopy(bench)}]}, scales)
    assert scaled["gpus"][0]["costs"]["composite_sort_last"] == pytest.approx(
        {"fixed_ns": 100.0, "ns_per_pixel": 3.0, "ns_per_input": 0.0}, rel=0.01)
    assert fit_alone_scales(measured[2:], ["composite_sort_last"], bench) == {}


def test_host_copy_wake_is_measured_from_the_runs():
    """A host copy that starts 300 ns after its download ended, its thread idle, is found to
    wake in 300 ns; the model without it starts the copy at once, and a run without host
    copies gives nothing."""
    from mgpusim.calibration.run_fit import fit_host_copy_wake
    prof = profile_dict(gpus=2)
    prof["host"]["host_copy_wake_ns"] = 300
    woke = make_experiment(copy.deepcopy(prof), gpus=2, width=32, height=16, iterations=40, frames=12)
    assert fit_host_copy_wake([(woke, simulate(woke).trace)]) == (300, 10)
    prof["host"]["host_copy_wake_ns"] = 0
    at_once = make_experiment(copy.deepcopy(prof), gpus=2, width=32, height=16, iterations=40, frames=12)
    assert fit_host_copy_wake([(at_once, simulate(at_once).trace)])[0] == 0
    alone = make_experiment(copy.deepcopy(prof), gpus=1, width=32, height=16, iterations=40, frames=12)
    assert fit_host_copy_wake([(alone, simulate(alone).trace)]) is None


def test_host_copy_wait_is_split_between_wake_and_dispatch():
    """A host copy waits its thread's wake latency and then the dispatch work: the measured
    wait (500 ns here) holds both, so the grid gives the wake what is left after each trial's
    dispatch, and gets back the 300 ns wake and 200 ns dispatch that made the runs (counting
    the whole wait as the wake would make every host copy start 200 ns late)."""
    from mgpusim.calibration.run_fit import copy_wake_after_dispatch, fit_host_copy_wake
    prof = profile_dict(gpus=2)
    prof["host"].update(host_copy_wake_ns=300, dispatch_ns=200)
    made = [make_experiment(copy.deepcopy(prof), gpus=2, width=w, height=16, iterations=it,
                            frames=12) for w, it in ((32, 40), (64, 10))]
    measured = [(exp, simulate(exp).trace) for exp in made]
    wait, _copies = fit_host_copy_wake(measured)
    assert wait == 500
    start = copy.deepcopy(prof)
    start["host"].update(host_copy_wake_ns=wait, dispatch_ns=0)
    found, score = fit_host_effects(start, measured, {"dispatch_ns": (0, 100, 200, 400)}, wait)
    assert found == {"dispatch_ns": 200, "host_copy_wake_ns": 300}
    assert score == pytest.approx(0.0, abs=1e-9)
    assert copy_wake_after_dispatch(150, 200) == 0  # never negative


def test_copy_setup_is_measured_on_the_runs_copies():
    """Copies that cost 700 ns more than bytes over the link are found to have a 700 ns fixed
    cost on their queue family, whatever the profile being fitted says it is; 1-GPU runs (no
    copies) give nothing."""
    from mgpusim.calibration.run_fit import fit_copy_setup
    prof = profile_dict(gpus=2, latency=7)
    prof["gpus"][0]["copy"] = {"transfer": {"fixed_ns": 700}}
    two = make_experiment(copy.deepcopy(prof), gpus=2, width=32, height=16, iterations=40, frames=12)
    fitting = copy.deepcopy(prof)
    fitting["gpus"][0]["copy"] = {"transfer": {"fixed_ns": 100}}
    found = fit_copy_setup([(two, simulate(two).trace)], fitting)
    assert set(found) == {"transfer"}
    fixed, copies = found["transfer"]
    assert fixed == pytest.approx(700, abs=1) and copies >= 1
    one = make_experiment(copy.deepcopy(prof), gpus=1, width=32, height=16, iterations=40, frames=12)
    assert fit_copy_setup([(one, simulate(one).trace)], fitting) == {}


def test_an_alone_scale_is_never_negative(monkeypatch):
    """Instances alone shorter than the fixed cost (a noisy machine's small composites) give a
    scale of 0, not a negative coefficient that the profile would refuse."""
    from mgpusim.calibration import run_fit as r

    task = r.PassTask("comp", "composite", None, "composite_sort_last",
                      {"pixel": 1000.0, "input": 2.0}, ())
    bench = {"composite_sort_last": {"fixed_ns": 100_000.0, "ns_per_pixel": 2.0, "ns_per_input": 10.0}}
    monkeypatch.setattr(r, "_alone_instances",
                        lambda runs: iter([(task, 60_000), (task, 80_000), (task, 90_000)]))
    assert r.fit_alone_scales([], ["composite_sort_last"], bench) == {"composite_sort_last": (0.0, 3)}
