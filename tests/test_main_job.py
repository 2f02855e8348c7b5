"""The README's main job end to end on lavapipe: the shipped study, cut to a few calibration
configurations and one short round of microbenchmarks, with one run per configuration."""
from __future__ import annotations

import json
import os

import pandas as pd
import pytest
import tomli_w

from mgpusim import load_profile
from mgpusim.cli import main
from mgpusim.commands.main_job import LAVAPIPE_STUDY
from mgpusim.model.toml_checks import read_toml
from mgpusim.studies import load_study

#: one configuration of each schedule, 1 and 2 GPUs
KEEP = ("sf_1gpu_128x96_it500", "sl_1gpu_256x192_t5k", "sort_first_2gpu", "sort_last_2gpu",
        "afr_2gpu", "xr_2gpu")


@pytest.fixture
def short_study():
    data = read_toml(LAVAPIPE_STUDY)
    data["microbenchmarks"].update(rounds=1, reps=2, warmup=1)
    data["calibration"]["config"] = [c for c in data["calibration"]["config"] if c["name"] in KEEP]
    path = LAVAPIPE_STUDY.with_name(f"short_study_{os.getpid()}_tmp.toml")  # beside it: its paths are relative
    path.write_text(tomli_w.dumps(data))
    yield path
    path.unlink()


@pytest.mark.vulkan
def test_main_job_measures_calibrates_validates_and_reports(tmp_path, short_study):
    out = tmp_path / "main"
    status = main(["main", "--out", str(out), "--repeats", "1", "--run-seconds", "0.1",
                   "--study", str(short_study)])
    # a verdict either way: 0 every target met, 1 one missed or not shown met (a noisy machine)
    assert status in (0, 1)
    profile = load_profile(out / "profile.toml")
    assert profile.host.gpus_share_cpu and profile.gpus[0].task_gap_ns > 0
    threads = load_study(LAVAPIPE_STUDY).lavapipe_threads()
    assert profile.gpus[0].cpu_threads == threads  # what every run of the profile will use
    assert "mesh: cores=" in (out / "profile.toml").read_text()
    stats = json.loads((out / "errors.json").read_text())["Calibration runs (seen by the fit)"]
    assert stats["configurations"] == len(KEEP)
    for name in ("sort_first_2gpu", "sort_last_2gpu", "xr_2gpu"):
        summary = json.loads((out / "validation" / name / "summary.json").read_text())
        assert abs(summary["frame_time_error"]) < 1.0  # finite and not absurd on a noisy machine
        assert (out / "validation" / name / "timelines.png").is_file()
        assert (out / "validation" / name / "measured.perfetto.json").is_file()
    report = (out / "report.md").read_text()
    assert "| sort_first_2gpu |" in report and "### Calibration runs: xr" in report
    assert "| step most off (simulated - measured) |" in report and " ms (" in report
    # the machine's speed, probed before and after the microbenchmarks and around the runs
    probes = pd.concat([pd.read_csv(out / f / "speed_probe.csv") for f in ("measurements", "runs")])
    assert probes["point"].tolist() == ["before the microbenchmarks"] * 2 + [
        "after the microbenchmarks"] * 2 + ["runs, round 1 of 1"] * 2 + ["after the runs"] * 2
    assert (probes["median_ms"] > 0).all()
    assert "## The machine's speed during the job" in report
    # and before and after every run: each run predicted at its own speed
    runs = pd.read_csv(out / "runs" / "run_speed.csv")
    assert sorted(runs["config"]) == sorted(KEEP) and (runs[["before_ms", "after_ms"]] > 0).all().all()
    assert (runs["after_ms"].iloc[:-1].to_numpy() == runs["before_ms"].iloc[1:].to_numpy()).all()
    summary = json.loads((out / "validation" / "afr_2gpu" / "summary.json").read_text())
    row = runs.set_index("config").loc["afr_2gpu"]
    assert summary["speed"]["probe_before_ms"] == pytest.approx(row["before_ms"])
    assert summary["speed"]["probe_ratio"] > 0 and "normalized error" in report
    assert report.splitlines()[2].startswith("**Verdict on the") and "band" in report.splitlines()[2]
    assert json.loads((out / "verdict.json").read_text())["exit_status"] == status
