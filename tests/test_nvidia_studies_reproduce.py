"""Every real-GPU study's error tables come back offline: `mgpusim study validate STUDY
--held-out` on the committed tables, runs and profile gives the committed
`errors_by_schedule.json` (prediction and replay, per schedule, calibration and held-out runs).
Tables only (`--no-figures`), so that the four studies take seconds, not minutes."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from mgpusim.cli import main

ROOT = Path(__file__).resolve().parents[1]

#: study -> the data folder holding its runs and committed error tables
STUDIES = {"h100_x2": "h100_x2", "h100_x4": "h100_x4", "h200_x4": "h200_x4", "h200": "h200_x2"}


def _close(got: object, want: object, where: str) -> None:
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        for key in want:
            _close(got[key], want[key], f"{where}.{key}")
    elif isinstance(want, float):
        assert isinstance(got, (int, float)) and math.isclose(got, want, rel_tol=1e-6, abs_tol=1e-9), \
            (where, got, want)
    else:
        assert got == want, where


@pytest.mark.parametrize("study", sorted(STUDIES))
def test_study_validate_reproduces_the_committed_error_tables(tmp_path: Path, study: str) -> None:
    args = ["study", "validate", str(ROOT / "experiments" / study / "study.toml"), "--held-out",
            "--no-figures", "--out", str(tmp_path)]
    assert main(args) == 0
    got = json.loads((tmp_path / "errors_by_schedule.json").read_text())
    want = json.loads((ROOT / "data" / "nvidia" / STUDIES[study] / "errors_by_schedule.json").read_text())
    assert any("Held-out" in half for half in want)  # the held-out runs are compared
    _close(got, want, study)
    assert not list((tmp_path / "validation").glob("*/timelines.png"))  # tables only


def test_no_figures_changes_no_number(tmp_path: Path) -> None:
    """The figures are drawn from the comparison, never feed it: one study's held-out tables
    are the same with and without them."""
    study = str(ROOT / "experiments" / "h200" / "study.toml")
    assert main(["study", "validate", study, "--out", str(tmp_path / "a")]) == 0
    assert main(["study", "validate", study, "--no-figures", "--out", str(tmp_path / "b")]) == 0
    assert list((tmp_path / "a" / "validation").glob("*/timelines.png"))
    a, b = ((tmp_path / x / "errors_by_schedule.json").read_text() for x in "ab")
    assert a == b


def _python_runs_study(tmp_path: Path, shared: bool) -> Path:
    """The 4x H200 study on the Python executor's runs (`data/nvidia/h200_x4/runs`, the
    study's before the native runner core), its profile's host threads taking turns on one
    interpreter lock as that executor's did (`serial_dispatch`) or, as a what-if, sharing it
    (`host.shared_interpreter`), the grid then searching each task's submit work on the
    interpreter beside the wake-up's dispatch work."""
    here = ROOT / "experiments" / "h200_x4"
    folder = tmp_path / ("shared" if shared else "serial")
    folder.mkdir()
    profile = (ROOT / "hardware_profiles" / "h200_x4.toml").read_text()
    assert "\nserial_dispatch = false\n" in profile  # the native core's threads wake together
    turns = "shared_interpreter = true" if shared else "serial_dispatch = true"
    profile = profile.replace("\nserial_dispatch = false\n", f"\n{turns}\n", 1)
    (folder / "h200_x4_python.toml").write_text(profile)
    root = os.path.relpath(ROOT, folder)  # the study's paths must be relative to it
    text = (here / "study.toml").read_text().replace('"../../', f'"{root}/')
    text = text.replace("/data/nvidia/h200_x4/runs_native_2026-11-27", "/data/nvidia/h200_x4/runs")
    text = text.replace(f'"{root}/hardware_profiles/h200_x4.toml"', '"h200_x4_python.toml"')
    text = text.replace('experiment = "', f'experiment = "{root}/experiments/h200_x4/')
    if shared:
        grid = ("dispatch_ns = [0, 50000, 100000, 150000, 200000, 300000, 400000, 600000]\n"
                "submit_ns = [0, 25000, 50000, 100000, 150000, 200000, 300000]\n")
        head, rest = text.split("[calibration.host_grid]\n", 1)
        text = head + "[calibration.host_grid]\n" + grid + rest.split("\n", 1)[1]
    study = folder / "study.toml"
    study.write_text(text)
    return study


def _calibrated_errors(study: Path) -> dict:
    out = study.parent
    assert main(["study", "calibrate", str(study), "--out", str(out / "cal")]) == 0
    assert main(["study", "validate", str(study), "--held-out", "--no-figures",
                 "--profile", str(out / "cal" / "profile.toml"), "--out", str(out / "v")]) == 0
    return json.loads((out / "v" / "errors_by_schedule.json").read_text())


@pytest.mark.second_step  # two full calibrations of the 4x H200 study (about a minute)
def test_a_shared_interpreter_fits_the_python_executors_sort_first_replay(tmp_path: Path) -> None:
    """What docs/nvidia_h200_x4.md reports of the what-if on the Python executor's runs:
    calibrated with the runner's threads sharing one interpreter, the grid gives each task
    submit work on it, and the replay of the calibration half's sort-first runs falls from a
    9 % median miss (threads taking turns) to under half of it, while the calibration half's XR
    replay gets worse (why that profile left it off)."""
    serial = _calibrated_errors(_python_runs_study(tmp_path, shared=False))
    shared_study = _python_runs_study(tmp_path, shared=True)
    shared = _calibrated_errors(shared_study)
    fitted = (shared_study.parent / "cal" / "profile.toml").read_text()
    assert "shared_interpreter = true" in fitted and "submit_ns = 100000" in fitted
    cal = "Calibration runs (seen by the fit)"
    key = "replay_median_abs_frame_time_error"
    assert serial[cal]["sort_first"][key] > 0.08
    assert shared[cal]["sort_first"][key] < 0.5 * serial[cal]["sort_first"][key]
    assert shared[cal]["xr"][key] > 0.02 and serial[cal]["xr"][key] < 0.01
