"""The two-H200 study re-validated and re-calibrated offline from its committed runs and tables.

The runs under data/nvidia/h200_x2/ were measured on 2x NVIDIA H200 (driver 580, one VkDevice per
GPU; data/nvidia/README.md says how); the profile is the calibrated hardware_profiles/h200_x2.toml.
"""
from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.measure import run_archive
from mgpusim.studies import load_study, validate
from mgpusim.studies.measuring import measured_folder
from tests.nvlink_whatif import nvlink_whatif

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h200" / "study.toml"
CONFIG = "sf_4k_it500"


def test_validate_measured_h200_run_offline(tmp_path: Path) -> None:
    study = load_study(STUDY)
    entry = next(e for e in study.held_out if e.name == CONFIG)
    measured = measured_folder(study.held_out_runs, CONFIG)
    assert run_archive.is_file(measured / "trace.csv")  # committed packed: data/nvidia/h200_x2/runs_si
    args = ["validate", str(entry.experiment), "--profile", str(study.profile), "--measured", str(measured),
            "--out", str(tmp_path / "v")]
    for s in entry.sets:
        args += ["--set", s]
    assert main(args) == 0
    summary = json.loads((tmp_path / "v" / "summary.json").read_text())
    for key in ("frame_time_error", "latency_error"):
        assert math.isfinite(summary[key])
    steps = summary["step_errors"]
    assert {"render", "d2h", "host_copy", "h2d", "composite", "present"} <= set(steps)
    assert all(math.isfinite(v) for v in steps.values())
    # the committed calibration meets the study's bound on this held-out configuration
    assert abs(summary["frame_time_error"]) <= 0.15
    assert (tmp_path / "v" / "timelines.png").is_file()


def test_error_table_over_saved_runs(tmp_path: Path) -> None:
    study = load_study(STUDY)
    entries = tuple(e for e in study.held_out if e.name in (CONFIG, "sl_1080p_t3M"))
    table = validate(study, entries, study.held_out_runs, study.profile, tmp_path, lambda m: None)
    assert list(table["config"]) == [CONFIG, "sl_1080p_t3M"]
    assert table["frame_time_error"].abs().max() <= 0.15
    assert not table.drop(columns="run_to_run_spread").isna().any().any()
    # every row says where it differs most
    assert (table["step_most_off"] != "").all() and (table["wait_most_off"] != "").all()


def _flat(d: object, prefix: str = "") -> dict[str, object]:
    if isinstance(d, dict):
        return {k2: v for k, v in d.items() for k2, v in _flat(v, f"{prefix}.{k}").items()}
    if isinstance(d, list):
        return {k2: v for i, v in enumerate(d) for k2, v in _flat(v, f"{prefix}.{i}").items()}
    return {prefix: d}


@pytest.mark.parametrize("study, profile", [("h200/study.toml", "h200_x2.toml"),
                                            ("h100/study.toml", "h100.toml")])
def test_study_calibration_rebuilds_the_committed_profile(tmp_path: Path, study: str, profile: str) -> None:
    """Tables, host copy table, runner-form refits on the calibration runs and the dispatch
    search give every number of the committed profile back."""
    assert main(["study", "calibrate", str(ROOT / "experiments" / study), "--out", str(tmp_path)]) == 0
    fitted = _flat(tomllib.loads((tmp_path / "profile.toml").read_text()))
    committed = _flat(tomllib.loads((ROOT / "hardware_profiles" / profile).read_text()))
    numbers = {k for k, v in committed.items() if not k.startswith(".sources")}
    assert {k: fitted.get(k) for k in numbers} == {k: committed[k] for k in numbers}


def test_nvlink_whatif_is_faster_than_pcie() -> None:
    table = nvlink_whatif(load_study(STUDY))
    assert len(table) == 15  # every held-out configuration with two GPUs
    assert (table["nvlink_frame_ms"] <= table["measured_links_frame_ms"] * 1.0001).all()
    assert (table["nvlink_groups_frame_ms"] <= table["measured_links_frame_ms"] * 1.0001).all()


@pytest.mark.parametrize("profile", ["h200_x2.toml", "h100.toml"])
def test_nvidia_profiles_load(profile: str) -> None:
    from mgpusim.schedules.experiment import load_experiment
    exp = load_experiment(ROOT / "experiments" / "h200" / "sort_first.toml", {"schedule.gpus": 1},
                          profile=str(ROOT / "hardware_profiles" / profile))
    assert exp.profile.host.memcpy_threads == 8
