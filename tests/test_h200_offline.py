"""`validate --measured` on a committed two-H200 run, with no device (issue 5).

The run folder data/nvidia/h200x2/runs_si/sf_4k_it500 was measured on 2x NVIDIA H200 by
data/nvidia/run_h200x2_c.sh; the profile is the calibrated hardware_profiles/h200_x2.toml.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from mgpusim import nvidia
from mgpusim.cli import main

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "sf_4k_it500"


def test_validate_measured_h200_run_offline(tmp_path: Path) -> None:
    config = next(c for c in nvidia.load_configs() if c.name == CONFIG)
    measured = nvidia.MEASURED / CONFIG
    assert (measured / "trace.csv").is_file()
    args = ["validate", str(config.experiment), "--profile", str(nvidia.PROFILE), "--measured", str(measured),
            "--out", str(tmp_path / "v")]
    for s in config.sets:
        args += ["--set", s]
    assert main(args) == 0
    summary = json.loads((tmp_path / "v" / "summary.json").read_text())
    for key in ("frame_time_error", "latency_error"):
        assert math.isfinite(summary[key])
    steps = summary["step_errors"]
    assert {"render", "d2h", "host_copy", "h2d", "composite", "present"} <= set(steps)
    assert all(math.isfinite(v) for v in steps.values())
    # the committed calibration meets the bound on this held-out configuration
    assert abs(summary["frame_time_error"]) <= 0.15
    assert (tmp_path / "v" / "timelines.png").is_file()


def test_error_table_over_saved_runs(tmp_path: Path) -> None:
    table = nvidia.validate_saved(out=tmp_path, names=[CONFIG, "sl_1080p_t3M"])
    assert list(table["config"]) == [CONFIG, "sl_1080p_t3M"]
    assert table["frame_time_error"].abs().max() <= 0.15
    assert not table.isna().any().any()


@pytest.mark.parametrize("profile", ["h200_x2.toml", "h100.toml"])
def test_nvidia_profiles_load(profile: str) -> None:
    from mgpusim.experiment import load_experiment
    exp = load_experiment(ROOT / "experiments" / "h200" / "sort_first.toml", {"schedule.gpus": 1},
                          profile=str(ROOT / "hardware_profiles" / profile))
    assert exp.profile.host.memcpy_threads == 8
