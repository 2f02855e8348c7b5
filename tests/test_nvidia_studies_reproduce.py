"""Every real-GPU study's error tables come back offline: `mgpusim study validate STUDY
--held-out` on the committed tables, runs and profile gives the committed
`errors_by_schedule.json` (prediction and replay, per schedule, calibration and held-out runs).
Tables only (`--no-figures`), so that the four studies take seconds, not minutes."""
from __future__ import annotations

import json
import math
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
