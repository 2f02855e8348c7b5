"""A study uses only its own runs, and all of them unless told otherwise: another study's runs,
an empty folder, a file, a copy cut short or one set given twice are refused in one line that
says what was expected, before any fit or comparison."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.studies import floor, pipeline, run_sets
from mgpusim.studies.study_file import load_study

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h100_x2" / "study.toml"
RUNS = ROOT / "data" / "nvidia" / "h100_x2" / "runs"
OTHER_RUNS = ROOT / "data" / "nvidia" / "h100_x4" / "runs"


@pytest.fixture(scope="module")
def study():
    return load_study(STUDY)


@pytest.fixture
def unpacked(tmp_path: Path) -> Path:
    """A copy of the study's committed runs, as files on disk (to edit)."""
    root = tmp_path / "runs"
    shutil.copytree(RUNS, root)
    run_archive.unpack(root)
    return root


def _refused(call, *args, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        call(*args, **kwargs)
    return str(info.value)


def test_the_committed_runs_are_the_studys_own_and_complete(study) -> None:
    for entries in (study.calibration, study.held_out):
        assert run_sets.check_half(study, entries, RUNS, "--runs").missing == ()


def test_an_empty_folder_a_file_or_nothing_is_refused(study, tmp_path: Path) -> None:
    assert "holds no measured run" in _refused(run_sets.check_half, study, study.calibration, tmp_path, "--runs")
    (tmp_path / "f").write_text("x")
    assert "is a file" in _refused(run_sets.check_half, study, study.calibration, tmp_path / "f", "--runs")
    message = _refused(run_sets.check_half, study, study.calibration, tmp_path / "none", "")
    assert "no such runs folder" in message and "mgpusim study measure" in message


def test_another_studys_runs_are_refused_naming_what_was_expected(study) -> None:
    message = _refused(run_sets.check_half, study, study.calibration, OTHER_RUNS, "--runs")
    assert "another study" in message and "afr4_" in message and "afr_1gpu" in message


def test_partial_coverage_is_an_error_unless_allowed(study, unpacked: Path) -> None:
    gone = study.calibration[0].name
    shutil.rmtree(unpacked / gone)
    message = _refused(run_sets.check_half, study, study.calibration, unpacked, "--runs")
    assert gone in message and "--allow-missing" in message and "1 of the 9" in message
    coverage = run_sets.check_half(study, study.calibration, unpacked, "--runs", allow_missing=True)
    assert coverage.missing == (gone,)
    lines = pipeline._missing_lines({pipeline.CALIBRATION_TITLE: list(coverage.missing)})
    assert lines and gone in lines[0] and lines[0].startswith("**Not every configuration")


def test_a_run_of_another_card_or_experiment_is_refused(study, unpacked: Path) -> None:
    name = study.held_out[0].name
    machine = next((unpacked / name).rglob("machine.json"))
    record = json.loads(machine.read_text())
    record["gpus"][0]["device"] = "NVIDIA H200"
    machine.write_text(json.dumps(record))
    for folder in (unpacked / name).iterdir():  # whichever run is compared
        if folder.is_dir():
            (folder / "machine.json").write_text(json.dumps(record))
    message = _refused(run_sets.check_half, study, study.held_out, unpacked, "--runs")
    assert "NVIDIA H200" in message and "another machine" in message


def test_a_runs_folder_measured_for_another_study_is_refused(study, unpacked: Path) -> None:
    (unpacked / "study.json").write_text(json.dumps({"study": "lavapipe"}))
    assert "runs of study 'lavapipe'" in _refused(run_sets.check_set, study, unpacked, "--runs")
    (unpacked / "study.json").write_text(json.dumps({"study": study.name}))
    assert run_sets.check_set(study, unpacked, "--runs")


def test_a_floor_refuses_a_set_twice_a_copy_or_another_studys_set(study, tmp_path: Path) -> None:
    assert "same runs" in _refused(floor.check_sets, study, [RUNS, RUNS])
    copy = tmp_path / "copy"
    shutil.copytree(RUNS, copy)
    assert "same runs" in _refused(floor.check_sets, study, [RUNS, copy])
    assert "another study" in _refused(floor.check_sets, study, [RUNS, OTHER_RUNS])


@pytest.mark.parametrize("step", ["validate", "calibrate"])
def test_the_commands_refuse_before_any_work(step: str, tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "mgpusim", "study", step, str(STUDY), "--runs",
                           str(OTHER_RUNS), "--out", str(tmp_path / "out")], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 2, done.stderr
    assert "another study" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "out" / "profile.toml").exists()


def test_a_missing_data_folder_says_an_installed_package_lacks_it(tmp_path: Path, monkeypatch) -> None:
    """From an installed wheel (no data/ beside the package) a shipped study's committed runs
    are missing: the error says why, not only which folder."""
    from mgpusim.studies import study_file
    text = STUDY.read_text()  # its data paths (../../data/...) lead nowhere from tmp_path
    (tmp_path / "experiments" / "h100_x2").mkdir(parents=True)
    moved = tmp_path / "experiments" / "h100_x2" / "study.toml"
    moved.write_text(text.replace('"../../hardware_profiles/', f'"{os.path.relpath(ROOT, moved.parent)}/hardware_profiles/'))
    monkeypatch.setattr(study_file, "PACKAGE", tmp_path / "mgpusim")
    message = _refused(load_study, moved)
    assert "data/nvidia/h100_x2" in message and "checkout" in message
    monkeypatch.setattr(study_file, "PACKAGE", ROOT / "mgpusim")
    assert "checkout" not in _refused(load_study, moved)
