"""`mgpusim run` writes the measured run that `mgpusim validate --measured` reads."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.vulkan
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))
EXPERIMENT = Path(ROOT) / "experiments" / "lavapipe" / "sort_first.toml"


def test_run_command_writes_the_measured_run(tmp_path):
    out = tmp_path / "m"
    cmd = [sys.executable, "-m", "mgpusim.cli", "run", "experiments/sort_first_tc1.toml",
           "--set", "schedule.gpus=2", "--set", "scene.width=64", "--set", "scene.height=32",
           "--set", 'scene.passes=[{name="f",kind="fragment_loop",iterations=20}]',
           "--set", "schedule.frames=4", "--set", "schedule.warmup_frames=1",
           "--host-threads", "2", "--out", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in out.iterdir()} >= {"trace.csv", "frames.csv", "summary.json",
                                               "machine.json", "image.png"}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["measured"] and summary["frame_time_ms"] > 0
    assert len(pd.read_csv(out / "frames.csv")) == 4
    assert json.loads((out / "machine.json").read_text())["gpus"][0]["device"]


def test_bad_device_is_one_line(tmp_path):
    cmd = [sys.executable, "-m", "mgpusim.cli", "run", "experiments/sort_first_tc1.toml",
           "--devices", "7,8", "--out", str(tmp_path)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "no physical device 7" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_validate_measures_repeated_runs_and_compares_their_steady_window(tmp_path):
    """By default `validate` takes several runs, compares their steady window, reports spread."""
    out = tmp_path / "v"
    from mgpusim.cli import main
    assert main(["validate", str(EXPERIMENT), "--set", "scene.width=64", "--set", "scene.height=48",
                 "--repeats", "2", "--run-seconds", "0.2", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["measured_runs"] == 2 and math.isfinite(summary["measured_spread"])
    assert summary["measured_from"].endswith("steady")
    assert (out / "measured" / "run0" / "trace.csv").is_file()
    assert (out / "measured" / "run1" / "trace.csv").is_file()
    runs = json.loads((out / "measured" / "runs.json").read_text())
    assert len(runs["frame_time_ms"]) == 2


LAVAPIPE = Path(ROOT) / "experiments" / "lavapipe"


@pytest.mark.parametrize("name, sets, width", [
    ("afr.toml", ["scene.passes.0.iterations=50"], 64),
    ("afr_temporal.toml", ["scene.passes.0.iterations=50", "schedule.gpus=3"], 64),
    ("pipelining.toml", ["scene.passes.0.output_bytes=12288", "scene.passes.1.output_bytes=12288",
                         "schedule.chunks=4"], 64),
    ("xr.toml", ["scene.passes.0.triangles=2000", "schedule.scaling=strong"], 128),
    ("particles.toml", ["schedule.particles=512"], 64),
])
def test_the_other_schedules_shipped_lavapipe_experiments_run(tmp_path, name, sets, width):
    """Each schedule's lavapipe experiment runs as shipped (made small): XR shows both eyes."""
    import matplotlib.image as mpimg

    from mgpusim.cli import main

    out = tmp_path / "m"
    small = ["scene.width=64", "scene.height=48", "schedule.frames=4", "schedule.warmup_frames=1"]
    argv = ["run", str(LAVAPIPE / name), "--out", str(out)]
    for item in small + sets:
        argv += ["--set", item]
    assert main(argv) == 0
    assert mpimg.imread(out / "image.png").shape[:2] == (48, width)
    assert json.loads((out / "summary.json").read_text())["frame_time_ms"] > 0


def test_a_run_uses_the_rasterizer_threads_its_lavapipe_profile_was_calibrated_with():
    """A profile's `cpu_threads` is how many rasterizer threads each lavapipe GPU ran with when
    it was calibrated: a run on that profile opens its GPUs with as many, unless told."""
    from dataclasses import replace

    from mgpusim.real.runner.execute import run_experiment
    from mgpusim.schedules.experiment import load_experiment, parse_overrides

    exp = load_experiment(EXPERIMENT, parse_overrides([
        "schedule.gpus=2", "scene.width=64", "scene.height=32", "schedule.frames=3",
        "schedule.warmup_frames=1", 'scene.passes=[{name="f",kind="fragment_loop",iterations=20}]']))
    profile = replace(exp.profile, gpus=tuple(replace(g, cpu_threads=3) for g in exp.profile.gpus))
    exp = replace(exp, profile=profile)
    assert [g["lp_num_threads"] for g in run_experiment(exp).machine["gpus"]] == [3, 3]
    told = run_experiment(exp, lp_threads=[1, 2]).machine["gpus"]
    assert [g["lp_num_threads"] for g in told] == [1, 2]


def test_a_measured_run_keeps_every_frame_so_it_is_bounded_below_the_models(tmp_path):
    """The model runs up to 10^7 frames where it fast-forwards; hardware never does, so a
    measured run (and its untimed pre-warm) stops at 10^6 with one error, nothing opened or
    written."""
    from mgpusim.cli import main
    out = tmp_path / "o"
    assert main(["run", "experiments/lavapipe/sort_first.toml", "--set", "schedule.frames=1000001",
                 "--out", str(out)]) == 2
    assert main(["run", "experiments/lavapipe/sort_first.toml", "--prewarm", "1000001",
                 "--out", str(out)]) == 2
    assert not out.exists()
