"""load_experiment hands back the experiment it loaded while the files it read are unchanged
(their bytes' digests), and loads again when either file changes or the profile the
experiment names is another file."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]


def _copy(tmp: Path) -> Path:
    shutil.copy(ROOT / "hardware_profiles" / "tc1.toml", tmp / "p.toml")
    text = (ROOT / "experiments" / "sort_first_tc1.toml").read_text()
    exp = tmp / "e.toml"
    exp.write_text("\n".join('profile = "p.toml"' if line.startswith("profile =") else line
                             for line in text.splitlines()) + "\n")
    return exp


def test_unchanged_files_give_the_same_experiment(tmp_path):
    path = _copy(tmp_path)
    first = load_experiment(path, {"schedule.frames": 40})
    assert load_experiment(path, {"schedule.frames": 40}) is first
    assert load_experiment(path, {"schedule.frames": 41}) is not first  # other overrides
    assert simulate(load_experiment(path, {"schedule.frames": 40})).summary == simulate(first).summary


def test_a_changed_file_is_read_again(tmp_path):
    path = _copy(tmp_path)
    first = load_experiment(path)
    path.write_text(path.read_text().replace("frames = 60", "frames = 33", 1))
    again = load_experiment(path)
    assert again is not first and again.schedule.frames == 33
    profile = tmp_path / "p.toml"
    profile.write_text(profile.read_text() + "\n")  # the same profile, other bytes
    assert load_experiment(path) is not again


def test_the_profile_is_found_again_from_the_working_folder(tmp_path):
    path = _copy(tmp_path)
    (tmp_path / "cwd").mkdir()
    before = os.getcwd()
    try:
        os.chdir(tmp_path / "cwd")
        first = load_experiment(path)
        assert Path(first.profile.source).resolve() == (tmp_path / "p.toml").resolve()
        shutil.copy(tmp_path / "p.toml", tmp_path / "cwd" / "p.toml")  # now found here first
        again = load_experiment(path)
        assert again is not first and Path(again.profile.source).resolve() == (tmp_path / "cwd" / "p.toml").resolve()
    finally:
        os.chdir(before)


def test_read_toml_parses_the_same_bytes_once_and_hands_out_copies(tmp_path):
    from mgpusim.model.toml_checks import read_toml

    path = tmp_path / "t.toml"
    path.write_text("[a]\nb = [1, 2]\n")
    first = read_toml(path)
    first["a"]["b"].append(3)  # a caller's change stays its own
    assert read_toml(path) == {"a": {"b": [1, 2]}}
    path.write_text("[a]\nb = [4]\n")
    assert read_toml(path) == {"a": {"b": [4]}}
