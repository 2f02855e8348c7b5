"""A sweep's resume key holds every file its points read: an edited profile makes new points
(never mixed with the old ones in the table); unchanged inputs resume without running a point."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from mgpusim.sweeps import grid as sweeps

ROOT = Path(__file__).resolve().parents[1]
GRID = {"schedule.gpus": [1, 2]}
KW = {"overrides": {"schedule.frames": 16, "schedule.warmup_frames": 4}, "progress": False, "workers": 1}


@pytest.fixture
def files(tmp_path: Path) -> Path:
    """sort_first_tc1 and its profile copied where the test may edit them."""
    (tmp_path / "hardware_profiles").mkdir()
    (tmp_path / "experiments").mkdir()
    shutil.copy(ROOT / "hardware_profiles" / "tc1.toml", tmp_path / "hardware_profiles" / "tc1.toml")
    shutil.copy(ROOT / "experiments" / "sort_first_tc1.toml", tmp_path / "experiments" / "sort_first_tc1.toml")
    return tmp_path


def _counting(monkeypatch: pytest.MonkeyPatch) -> list:
    ran: list = []
    real = sweeps.run_point
    monkeypatch.setattr(sweeps, "run_point", lambda *a: ran.append(a) or real(*a))
    return ran


def test_an_edited_profile_runs_every_point_again_and_is_not_mixed(files, monkeypatch):
    exp, profile = files / "experiments" / "sort_first_tc1.toml", files / "hardware_profiles" / "tc1.toml"
    before = sweeps.sweep(exp, GRID, files / "out", **KW)
    profile.write_text(profile.read_text().replace("ns_per_pixel_iteration = 0.0016",
                                                   "ns_per_pixel_iteration = 0.0032"))
    ran = _counting(monkeypatch)
    after = sweeps.sweep(exp, GRID, files / "out", **KW)
    assert len(ran) == 2  # both points again: each depends on the profile
    fresh = sweeps.sweep(exp, GRID, files / "fresh", **KW)
    assert after["frame_time_ms"].tolist() == fresh["frame_time_ms"].tolist()
    assert all(a > b for a, b in zip(after["frame_time_ms"], before["frame_time_ms"]))


def test_unchanged_inputs_resume_without_running_a_point(files, monkeypatch):
    exp = files / "experiments" / "sort_first_tc1.toml"
    before = sweeps.sweep(exp, GRID, files / "out", **KW)
    ran = _counting(monkeypatch)
    again = sweeps.sweep(exp, GRID, files / "out", **KW)
    assert ran == []
    assert again["frame_time_ms"].tolist() == before["frame_time_ms"].tolist()


def test_the_identity_names_each_input_file_and_the_version(files):
    exp = files / "experiments" / "sort_first_tc1.toml"
    identity = sweeps.point_identity(exp, GRID, {}, "full")
    assert set(identity["inputs"]) == {"experiment", str(Path("..") / "hardware_profiles" / "tc1.toml")}
    assert identity["mgpusim"]
    profile = files / "hardware_profiles" / "tc1.toml"
    profile.write_text(profile.read_text() + "\n# a comment: other bytes\n")
    sweeps.loader(exp)  # the same process: a new sweep reads the files again
    again = sweeps.point_identity(exp, GRID, {}, "full")
    assert again["inputs"] == identity["inputs"]  # (this loader read the bytes once)
    edited = sweeps.fresh_loader(exp) and sweeps.point_identity(exp, GRID, {}, "full")
    assert edited["inputs"]["experiment"] == identity["inputs"]["experiment"]
    assert edited["inputs"] != identity["inputs"]


def test_a_profile_grid_key_hashes_each_profile_it_names(files):
    exp = files / "experiments" / "sort_first_tc1.toml"
    other = files / "hardware_profiles" / "tc1_copy.toml"
    shutil.copy(files / "hardware_profiles" / "tc1.toml", other)
    grid = {"profile": ["../hardware_profiles/tc1.toml", "../hardware_profiles/tc1_copy.toml"]}
    identity = sweeps.point_identity(exp, grid, {}, "full")
    assert str(Path("..") / "hardware_profiles" / "tc1_copy.toml") in identity["inputs"]
