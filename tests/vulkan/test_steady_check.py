"""The steadiness check before a job, on real lavapipe probes."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.measure import speed_probe as speed

pytestmark = pytest.mark.vulkan


@pytest.fixture
def quick_checks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(speed, "CHECKS", 2)
    monkeypatch.setattr(speed, "CHECK_PAUSE_S", 0.0)


def test_the_check_measures_real_probes(quick_checks: None) -> None:
    rows = speed.check_steady(2, 9.0, lambda m: None)
    assert sorted({r["pass"] for r in rows}) == ["fragment_loop", "mesh"]
    assert len(rows) == 4 and all(r["median_ms"] > 0 for r in rows)


def test_main_stops_before_writing_anything_when_the_machine_moved(
        quick_checks: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "job"
    # no two real probes agree to a billionth: the check must stop the job
    assert main(["main", "--steady-check", "1e-9", "--out", str(out)]) == 3  # could not measure
    err = capsys.readouterr().err
    assert "the machine's speed moved before the job" in err and "--steady-check" in err
    assert not out.exists()
