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
STUDIES = {"h100_x2": "h100_x2", "h100_x4": "h100_x4", "h200_x4": "h200_x4", "h200": "h200x2"}


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


def _shared_interpreter_study(tmp_path: Path) -> Path:
    """The 4x H200 study as a what-if: its profile with `host.shared_interpreter` instead of
    `serial_dispatch`, and the grid searching each task's submit work on the interpreter beside
    the wake-up's dispatch work."""
    here = ROOT / "experiments" / "h200_x4"
    profile = (ROOT / "hardware_profiles" / "h200_x4.toml").read_text()
    # the interpreter shared instead of taken in turns (the profile's serial_dispatch)
    profile = profile.replace("\nserial_dispatch = true\n", "\n", 1)
    profile = profile.replace("\n[host]\n", "\n[host]\nshared_interpreter = true\n", 1)
    (tmp_path / "h200_x4_shared_interpreter.toml").write_text(profile)
    root = os.path.relpath(ROOT, tmp_path)  # the study's paths must be relative to it
    text = (here / "study.toml").read_text().replace('"../../', f'"{root}/')
    text = text.replace(f'"{root}/hardware_profiles/h200_x4.toml"', '"h200_x4_shared_interpreter.toml"')
    text = text.replace('experiment = "', f'experiment = "{root}/experiments/h200_x4/')
    grid = ("dispatch_ns = [0, 50000, 100000, 150000, 200000, 300000, 400000, 600000]\n"
            "submit_ns = [0, 25000, 50000, 100000, 150000, 200000, 300000]\n")
    head, rest = text.split("[calibration.host_grid]\n", 1)
    text = head + "[calibration.host_grid]\n" + grid + rest.split("\n", 1)[1]
    study = tmp_path / "study.toml"
    study.write_text(text)
    return study


def test_a_shared_interpreter_fits_the_4x_h200_sort_first_replay(tmp_path: Path) -> None:
    """What docs/nvidia_h200_x4.md reports of the what-if: calibrated with the runner's threads
    sharing one interpreter, the grid gives each task submit work on it, and the replay of the
    calibration half's sort-first runs falls from a 9 % median miss to under half of it, while
    the calibration half's XR replay gets worse (why the shipped profile leaves it off)."""
    study = _shared_interpreter_study(tmp_path)
    assert main(["study", "calibrate", str(study), "--out", str(tmp_path / "cal")]) == 0
    fitted = (tmp_path / "cal" / "profile.toml").read_text()
    assert "shared_interpreter = true" in fitted and "submit_ns = 100000" in fitted
    assert main(["study", "validate", str(study), "--held-out", "--no-figures",
                 "--profile", str(tmp_path / "cal" / "profile.toml"), "--out", str(tmp_path / "v")]) == 0
    got = json.loads((tmp_path / "v" / "errors_by_schedule.json").read_text())
    want = json.loads((ROOT / "data" / "nvidia" / "h200_x4" / "errors_by_schedule.json").read_text())
    cal = "Calibration runs (seen by the fit)"
    key = "replay_median_abs_frame_time_error"
    assert want[cal]["sort_first"][key] > 0.08
    assert got[cal]["sort_first"][key] < 0.5 * want[cal]["sort_first"][key]
    assert got[cal]["xr"][key] > 0.02 and want[cal]["xr"][key] < 0.01
