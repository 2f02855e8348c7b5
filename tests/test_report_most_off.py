"""The study report's pointers to where a configuration differs most (step, hand-off)."""
from __future__ import annotations

import math

import pandas as pd
import pytest

from mgpusim.studies.pipeline import markdown_table, most_off


def report(steps: dict[str, float], waits: dict[str, float]) -> dict:
    """A comparison's steps (error) and waits (measured - simulated ms, largest first)."""
    return {"steps": {k: {"error": e, "measured_ms": 1.0, "simulated_ms": 1.0 + e} for k, e in steps.items()},
            "waits": {k: {"difference_ms": d, "measured_ms": 0.5, "simulated_ms": 0.5 - d}
                      for k, d in waits.items()}}


def test_the_step_furthest_off_either_way_and_the_first_wait_are_named():
    r = report({"render": -0.07, "present": 0.05, "d2d": 0.12}, {"-1:render0 -> render1": 0.49, "queue -> acquire": -0.01})
    r["steps"]["render"].update(measured_ms=1.86, simulated_ms=1.73)  # -7 %, but 0.13 ms
    r["steps"]["d2d"].update(measured_ms=0.10, simulated_ms=0.112)  # +12 %, 0.012 ms
    out = most_off(r)
    assert out["step_most_off"] == "render" and out["step_error"] == -0.07
    assert out["step_difference_ms"] == pytest.approx(-0.13)
    assert (out["wait_most_off"], out["wait_difference_ms"]) == ("-1:render0 -> render1", 0.49)


def test_a_comparison_without_waits_names_none():
    out = most_off(report({"render": 0.01}, {}))
    assert out["wait_most_off"] == "" and math.isnan(out["wait_difference_ms"])


def test_the_markdown_table_shows_both():
    r = report({"render": -0.072}, {"-1:render0 -> render3": 0.49})
    r["steps"]["render"].update(measured_ms=1.863, simulated_ms=1.729)
    row = {"config": "xr_4gpu", "measured_frame_ms": 4.29, "simulated_frame_ms": 3.77,
           "frame_time_error": -0.121, "measured_latency_ms": 5.0, "simulated_latency_ms": 4.6,
           "latency_error": -0.08, "run_to_run_spread": 0.05, **most_off(r)}
    text = markdown_table(pd.DataFrame([row]))
    assert "| render -0.13 ms (-7%) | `-1:render0 -> render3` +0.49 ms |" in text
