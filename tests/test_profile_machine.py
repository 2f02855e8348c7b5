"""A profile records the machine it was calibrated on, and a comparison with another machine's
runs says so: its accuracy holds on its own machine."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.model.profile import CalibratedOn, load_profile
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.study_file import load_study
from mgpusim.validation.measured import other_machine
from mgpusim.validation.measured_check import machine_of

ROOT = Path(__file__).resolve().parents[1]
PROFILES = ROOT / "hardware_profiles"
RECORD = {"cpu": "AMD EPYC", "cpu_count": 4, "affinity_cpus": 2,
          "gpus": [{"device": "llvmpipe (LLVM 15.0.6, 256 bits)", "driver": "llvmpipe",
                    "driver_info": "Mesa 22.3.6 (LLVM 15.0.6)"}]}


def test_a_run_record_reads_as_a_machine():
    assert machine_of(RECORD) == CalibratedOn("AMD EPYC", 2, "llvmpipe (LLVM 15.0.6, 256 bits)",
                                              "llvmpipe Mesa 22.3.6 (LLVM 15.0.6)")
    assert machine_of({"cpu": "x"}) is None  # no GPUs recorded: unknown, not a difference


def test_the_committed_lavapipe_profile_knows_its_machine():
    profile = load_profile(PROFILES / "lavapipe_2core.toml")
    assert other_machine(profile, machine_of(RECORD)) is None
    elsewhere = other_machine(profile, machine_of({**RECORD, "cpu": "Intel Xeon", "affinity_cpus": 16}))
    assert elsewhere is not None and elsewhere["differs"] == ["cpu", "cpus"]
    assert elsewhere["run"]["cpus"] == 16 and elsewhere["profile"]["cpus"] == 2


def test_a_profile_without_its_machine_claims_nothing():
    assert load_profile(PROFILES / "tc1.toml").calibrated_on is None


def test_a_bad_machine_table_is_refused(tmp_path):
    text = (PROFILES / "lavapipe_2core.toml").read_text().replace("cpus = 2\n", "cpus = \"two\"\n", 1)
    path = tmp_path / "p.toml"
    path.write_text(text)
    with pytest.raises(InputError, match="sources.machine.cpus"):
        load_profile(path)


def test_validate_notes_a_profile_of_another_machine(tmp_path, capsys):
    """An H100 run compared on the H200 profile: summary.json and the console say that the
    profile was calibrated on another machine; on its own profile, nothing is said."""
    study = load_study(ROOT / "experiments" / "h100_x2" / "study.toml")
    entry = next(e for e in study.held_out if e.name == "afr_2gpu_1440p_it2000")
    args = ["validate", str(entry.experiment), "--measured",
            str(measured_folder(study.held_out_runs, entry.name))]
    for item in entry.sets:
        args += ["--set", item]
    assert main(args + ["--out", str(tmp_path / "own")]) == 0
    assert "profile_machine" not in json.loads((tmp_path / "own" / "summary.json").read_text())
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "h200"), "--profile", str(PROFILES / "h200_x2.toml")]) == 0
    summary = json.loads((tmp_path / "h200" / "summary.json").read_text())
    assert summary["profile_machine"]["differs"] == ["device"]
    assert "calibrated on another machine" in capsys.readouterr().out
