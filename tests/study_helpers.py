"""What the real-GPU studies' offline tests share: a study's calibration compared with its
committed profile, and one held-out configuration validated from the committed runs."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

from mgpusim.cli import main
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.study_file import load_study

ROOT = Path(__file__).resolve().parents[1]


def toml_body(path: Path) -> dict[str, Any]:
    return tomllib.loads(path.read_text())


def calibrated_and_committed(study: Path, profile: str, out: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """`mgpusim study calibrate STUDY` into `out`: (the profile it wrote, the committed one)."""
    assert main(["study", "calibrate", str(study), "--out", str(out)]) == 0
    return toml_body(out / "profile.toml"), toml_body(ROOT / "hardware_profiles" / profile)


def validate_held_out(study_path: Path, name: str, out: Path) -> dict[str, Any]:
    """`mgpusim validate` of held-out configuration `name` on its committed runs: its summary."""
    study = load_study(study_path)
    entry = next(e for e in study.held_out if e.name == name)
    args = ["validate", str(entry.experiment), "--measured", str(measured_folder(study.held_out_runs, name)),
            "--out", str(out / name)]
    for item in entry.sets:
        args += ["--set", item]
    assert main(args) == 0
    return json.loads((out / name / "summary.json").read_text())
