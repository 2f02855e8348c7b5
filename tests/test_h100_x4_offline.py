"""The 4x H100 study (five-step on 3 and 4 GPUs, AFR and XR on 4), offline: the committed tables
and runs (data/nvidia/h100_x4/, packed) give the committed profile again, held-out runs compare
as docs/nvidia_h100_x4.md says, and the copy table holds the rows of GPUs copying at once."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pandas as pd

from mgpusim.cli import main
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.spec import load_study

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h100_x4" / "study.toml"
DATA = ROOT / "data" / "nvidia" / "h100_x4"


def _body(path: Path) -> dict:
    return tomllib.loads(path.read_text())


def test_the_committed_tables_and_runs_give_the_committed_profile(tmp_path):
    assert main(["study", "calibrate", str(STUDY), "--out", str(tmp_path)]) == 0
    fitted, committed = _body(tmp_path / "profile.toml"), _body(ROOT / "hardware_profiles" / "h100_x4.toml")
    assert fitted["gpus"] == committed["gpus"] and fitted["host"] == committed["host"]
    assert committed["gpus"][0]["count"] == 4


def _validate(tmp_path: Path, name: str) -> dict:
    study = load_study(STUDY)
    entry = next(e for e in study.held_out if e.name == name)
    args = ["validate", str(entry.experiment), "--measured", str(measured_folder(study.held_out_runs, name)),
            "--out", str(tmp_path / name)]
    for item in entry.sets:
        args += ["--set", item]
    assert main(args) == 0
    return json.loads((tmp_path / name / "summary.json").read_text())


def test_held_out_five_step_runs_on_four_gpus_are_within_the_target(tmp_path):
    """A sort-last and a sort-first run on 4 GPUs, sizes the calibration never saw."""
    for name in ("sl4_portrait_t10M", "sf4_4k_it2000"):
        summary = _validate(tmp_path, name)
        assert summary["measured_runs"] == 2  # the steady window of two interleaved runs
        assert abs(summary["frame_time_error"]) <= 0.03, (name, summary["frame_time_error"])


def test_xr_strong_on_four_gpus_compares_with_the_present_on_the_one_graphics_queue(tmp_path):
    """The runner opens one VkQueue per family, so XR's present shares GPU 0's graphics queue
    with its rendering; the comparison finds that in the run's trace and models the run so
    (`queues_as_run`), and then strong scaling with 3 frames in flight is within the target."""
    summary = _validate(tmp_path, "xrs4_quest3_t3M_fif3")
    assert summary["queues_as_run"] == {"gpu0.graphics#1": "gpu0.graphics"}
    assert abs(summary["frame_time_error"]) <= 0.03, summary["frame_time_error"]


def test_the_copy_tables_hold_gpus_copying_at_once():
    """d2h and h2d were timed alone and with 2 and 4 GPUs copying at once (one row per GPU);
    the profile's link rates come from the rows of one GPU alone."""
    for path in ("d2h", "h2d"):
        df = pd.read_csv(DATA / "measurements" / f"copy_{path}.csv")
        counts = df.groupby("gpus")["gpu"].nunique().to_dict()
        assert counts == {1: 1, 2: 2, 4: 4}
