"""The 4x H200 study (every schedule on a 4-GPU machine), offline: the committed tables and runs
(data/nvidia/h200_x4/, packed) give the committed profile again, held-out runs compare as
docs/nvidia_h200_x4.md says, and the copy tables hold the rows of GPUs copying at once."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pandas as pd

from mgpusim.cli import main
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.spec import load_study

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h200_x4" / "study.toml"
DATA = ROOT / "data" / "nvidia" / "h200_x4"


def _body(path: Path) -> dict:
    return tomllib.loads(path.read_text())


def test_the_committed_tables_and_runs_give_the_committed_profile(tmp_path):
    assert main(["study", "calibrate", str(STUDY), "--out", str(tmp_path)]) == 0
    fitted, committed = _body(tmp_path / "profile.toml"), _body(ROOT / "hardware_profiles" / "h200_x4.toml")
    assert fitted["gpus"] == committed["gpus"] and fitted["host"] == committed["host"]
    assert committed["gpus"][0]["count"] == 4 and committed["gpus"][0]["name"] == "NVIDIA H200"
    assert "ns_per_particle_pixel" in committed["gpus"][0]["costs"]["particle_render"]


def _validate(tmp_path: Path, name: str) -> dict:
    study = load_study(STUDY)
    entry = next(e for e in study.held_out if e.name == name)
    args = ["validate", str(entry.experiment), "--measured", str(measured_folder(study.held_out_runs, name)),
            "--out", str(tmp_path / name)]
    for item in entry.sets:
        args += ["--set", item]
    assert main(args) == 0
    return json.loads((tmp_path / name / "summary.json").read_text())


def test_held_out_particle_offload_and_pipelining_are_within_the_target(tmp_path):
    """Particle offload at 4x the calibrated particles on 4K (whose draw the particle_pixel term
    prices) and pipelining with 4 chunks at 4K, on two of the four GPUs."""
    for name in ("part4_2gpu_4k_p262k", "pipe4_2gpu_4k_chunks4"):
        summary = _validate(tmp_path, name)
        assert summary["measured_runs"] == 2  # the steady window of two interleaved runs
        assert abs(summary["frame_time_error"]) <= 0.05, (name, summary["frame_time_error"])
        assert abs(summary["replay_frame_time_error"]) <= 0.01, (name, summary["replay_frame_time_error"])


def test_the_copy_tables_hold_gpus_copying_at_once():
    """d2h and h2d were timed alone and with 2 and 4 GPUs copying at once (one row per GPU);
    four at once each get less than one alone (the host side of PCIe)."""
    for path in ("d2h", "h2d"):
        df = pd.read_csv(DATA / "measurements" / f"copy_{path}.csv")
        assert df.groupby("gpus")["gpu"].nunique().to_dict() == {1: 1, 2: 2, 4: 4}
        big = df[df["bytes"] == df["bytes"].max()]
        rate = (big["bytes"] / big["duration_ns"]).groupby(big["gpus"]).median()
        assert rate[4] < 0.9 * rate[1]
