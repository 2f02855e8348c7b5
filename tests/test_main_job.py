"""The README's main job end to end on lavapipe, with one run per configuration (~20 s)."""
from __future__ import annotations

import json

import pytest

from mgpusim import load_profile
from mgpusim.cli import main
from mgpusim.commands.main_job import LAVAPIPE_STUDY
from mgpusim.study import load_study


@pytest.mark.vulkan
def test_main_job_measures_calibrates_validates_and_reports(tmp_path):
    out = tmp_path / "main"
    assert main(["main", "--out", str(out), "--repeats", "1", "--run-seconds", "0.1"]) == 0
    profile = load_profile(out / "profile.toml")
    assert profile.host.gpus_share_cpu and profile.gpus[0].task_gap_ns > 0
    stats = json.loads((out / "errors.json").read_text())["Calibration runs (seen by the fit)"]
    assert stats["configurations"] == len(load_study(LAVAPIPE_STUDY).calibration)
    for name in ("sort_first_2gpu", "sort_last_2gpu"):
        summary = json.loads((out / "validation" / name / "summary.json").read_text())
        assert abs(summary["frame_time_error"]) < 1.0  # finite and not absurd on a noisy machine
        assert (out / "validation" / name / "timelines.png").is_file()
        assert (out / "validation" / name / "measured.perfetto.json").is_file()
    assert "| sort_first_2gpu |" in (out / "report.md").read_text()
