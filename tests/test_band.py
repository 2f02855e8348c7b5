"""The calibration's standard errors travel from the fit into the profile and into simulated
results as a band (frame_time_ms_lo/hi, latency_ms_lo/hi)."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.model.profile import load_profile
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
TABLES = [ROOT / "data" / "lavapipe" / f"{t}.csv" for t in ("fragment_loop", "mesh", "copy_d2d", "copy_d2h",
                                                           "copy_h2d", "host_copy",
                                                           "composite_sort_first", "composite_sort_last")]
EXPERIMENT = ROOT / "experiments" / "lavapipe" / "sort_first.toml"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("band") / "p.toml"
    assert main(["calibrate", *map(str, TABLES), "--out", str(out)]) == 0
    return out


def test_calibrate_writes_standard_errors(calibrated: Path) -> None:
    costs = tomllib.loads(calibrated.read_text())["gpus"][0]["costs"]
    assert costs["fragment_loop"]["stderr"]["ns_per_pixel_iteration"] > 0
    assert load_profile(calibrated).gpus[0].costs["fragment_loop"].stderr["pixel_iteration"] > 0


def test_simulate_reports_the_band_around_the_frame_time(calibrated: Path) -> None:
    exp = load_experiment(EXPERIMENT, {"schedule.frames": 30}, profile=str(calibrated))
    s = simulate(exp, band=True).summary
    assert s["frame_time_ms_lo"] < s["frame_time_ms"] < s["frame_time_ms_hi"]
    assert s["latency_ms_lo"] < s["latency_ms"] < s["latency_ms_hi"]
    assert "frame_time_ms_lo" not in simulate(exp).summary  # off unless asked for


def test_the_simulate_command_reports_the_band(calibrated: Path, tmp_path: Path, capsys) -> None:
    assert main(["simulate", str(EXPERIMENT), "--set", f'profile="{calibrated}"', "--set", "schedule.frames=30",
                 "--out", str(tmp_path / "o")]) == 0
    assert "calibration band" in capsys.readouterr().out


def test_a_profile_without_standard_errors_has_no_band() -> None:
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 20})
    assert "frame_time_ms_lo" not in simulate(exp, band=True).summary


def test_a_misspelt_standard_error_is_refused(calibrated: Path, tmp_path: Path) -> None:
    head, sep, tail = calibrated.read_text().partition("[gpus.costs.fragment_loop.stderr]")
    bad = tmp_path / "bad.toml"
    bad.write_text(head + sep + tail.replace("ns_per_pixel_iteration =", "ns_per_pixel_iteraton =", 1))
    with pytest.raises(InputError, match=r"fragment_loop\.stderr\.ns_per_pixel_iteraton.*did you mean"):
        load_profile(bad)
