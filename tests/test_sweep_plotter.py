"""`mgpusim sweep` draws its plot in a process forked before the model is imported
(mgpusim/sweeps/plotter.py): the same picture, byte for byte, as the sweep drawing it itself,
with matplotlib never imported by the sweep's own process; a sweep that ends without a plot
leaves no plotter behind."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.io.plot import sweep_png

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "sort_first_tc1.toml"
RUN = ("import sys; from mgpusim.cli import main; rc = main(sys.argv[1:]); "
       "print('matplotlib' in sys.modules); sys.exit(rc)")


def _sweep(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", RUN, "sweep", str(EXPERIMENT), "--no-progress", *args],
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize("grid", [  # a heatmap of two keys; lines over the first of three
    {"scene.width": "640,1024", "schedule.gpus": "1,2"},
    {"scene.width": "640,1024", "schedule.gpus": "1,2", "schedule.frames_in_flight": "1,2"}])
def test_the_plotter_draws_the_picture_the_sweep_would(tmp_path, grid):
    out = tmp_path / "sw"
    keys = [arg for key, values in grid.items() for arg in ("--grid", f"{key}={values}")]
    done = _sweep(*keys, "--fidelity", "analytic", "--workers", "1", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"  # the sweep's process never drew it
    df = pd.read_parquet(out / "sweep.parquet")
    here = sweep_png(df, list(grid), tmp_path / "here.png")
    assert (out / "sweep.png").read_bytes() == here.read_bytes()
    assert not list(out.glob(".*.tmp"))


def test_a_sweep_that_fails_leaves_no_plotter(tmp_path):
    """A grid key no value of which loads: one error, no folder; the plotter, handed nothing,
    exits with the command (the command's output pipes close: it holds them too)."""
    done = _sweep("--grid", "scene.widht=640", "--out", str(tmp_path / "sw"))
    assert done.returncode == 2 and "scene.widht" in done.stderr
    assert not (tmp_path / "sw" / "sweep.png").exists()
