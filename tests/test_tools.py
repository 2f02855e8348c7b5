"""The scripts under tools/ that no other test runs: the advice validation's entry points, the
particle sweep and the device-group listing. Each is loaded from its file as a user runs it."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pandas as pd
import pytest

from mgpusim.schedules.experiment import load_experiment

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "tools"


def _load(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(path.stem + "_tool", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("script", ["lavapipe.py", "h100_x4.py"])
def test_advice_validation_frames_load_on_their_profile(script: str) -> None:
    setup = _load(TOOLS / "advise_validation" / script).SETUP
    assert setup.profile.is_file()
    assert len(setup.frames) == 5
    for frame in setup.frames:
        exp = load_experiment(frame.experiment, frame.capture)
        assert exp.schedule.gpus == 1  # each frame is captured on one GPU, then advised


def test_advice_validation_shell_entry_names_an_existing_script() -> None:
    text = (TOOLS / "advise_validation" / "h100_x4.sh").read_text()
    named = [w.split("=", 1)[1] for w in text.split() if w.startswith("script=")]
    assert named and all((ROOT / n).is_file() for n in named)


def test_particle_sweep_covers_every_count_and_config(tmp_path: Path) -> None:
    out = tmp_path / "particles.csv"
    run = subprocess.run([sys.executable, str(TOOLS / "particles_sweep.py"), "--csv", str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    table = pd.read_csv(out)
    assert len(table) == 8 * 3
    one = table[table.config == "1gpu"].set_index("particles")
    # more particles cost the single GPU more frame time: the sweep varies what it says it does
    assert one.frame_time_ms.loc[1048576] > one.frame_time_ms.loc[256]


@pytest.mark.vulkan
def test_device_groups_lists_lavapipe() -> None:
    run = subprocess.run([sys.executable, str(TOOLS / "nvidia" / "device_groups.py")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert lines[0].endswith("physical-device group(s)") and int(lines[0].split()[0]) >= 1
    assert any("llvmpipe" in line for line in lines[1:])


def test_main_job_runs_tabulates_each_runs_verdict(tmp_path: Path) -> None:
    """The table of repeated main jobs: a run with a verdict gives its half, statuses and band;
    a run that wrote none says so (not dropped)."""
    tool = _load(TOOLS / "main_job_runs.py")
    (tmp_path / "index.txt").write_text("1 1764633600 371 1 1.50\n2 1764634000 400 3 2.00\n")
    run = tmp_path / "run1"
    run.mkdir()
    half = "Held-out runs (never seen by the fit)"
    (run / "verdict.json").write_text(json.dumps({"half": half, "line": "Replay met; prediction missed", "exit_status": 1}))
    verdict = {"replay": {"status": "met", "median": 0.004, "worst": 0.02},
               "prediction": {"status": "missed", "median": 0.05, "worst": 0.25, "flagged_runs": 3,
                              "band": {"median": [0.04, 0.06], "worst": [0.2, 0.3]}}}
    (run / "errors.json").write_text(json.dumps({half: {"verdict": verdict}}))
    table = tool.collect(tmp_path)
    assert table["run"].tolist() == [1, 2] and table["exit"].tolist() == [1, 3]
    first, second = table.iloc[0], table.iloc[1]
    assert (first.replay, first.prediction, first.prediction_median_band) == ("met", "missed", "4.0% to 6.0%")
    assert (first.replay_worst, first.prediction_worst, first.flagged_runs) == ("2.0%", "25.0%", 3)
    assert first.start_utc == "2025-12-02 00:00" and first.wall_s == 371
    assert second.line == "no verdict written" and second.half == ""
    assert tool.main(["--collect", str(tmp_path), "--table", str(tmp_path / "t.csv")]) == 0
    assert len(pd.read_csv(tmp_path / "t.csv")) == 2
