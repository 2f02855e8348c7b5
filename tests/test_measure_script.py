"""tools/nvidia/measure.sh, the NVIDIA studies' device script: with EXPECT_GPU it stops
at once, naming the cards, on a machine whose cards are not the study's (a request for one kind
of machine may be answered by another), and goes on where they are."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "nvidia" / "measure.sh"


def _run(tmp_path: Path, cards: list[str], expect: str) -> subprocess.CompletedProcess:
    """The script with a stand-in nvidia-smi that names `cards`, and no group to measure."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    smi = bin_dir / "nvidia-smi"
    smi.write_text("#!/bin/sh\n" + "".join(f"echo '{c}'\n" for c in cards))
    smi.chmod(0o755)
    study = tmp_path / "h100_x2"  # the script writes its measuring copy of the study there
    shutil.copytree(ROOT / "experiments" / "h100_x2", study)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "EXPECT_GPU": expect,
           "STUDY_DIR": str(study)}
    env.pop("OUT", None)
    return subprocess.run(["bash", str(SCRIPT), str(tmp_path / "work")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)


def test_other_cards_stop_it_before_anything_is_written(tmp_path):
    done = _run(tmp_path, ["NVIDIA H200", "NVIDIA H200"], "H100")
    assert done.returncode == 3
    assert "expected every card to be an H100, got: NVIDIA H200;NVIDIA H200;" in done.stderr
    assert not (tmp_path / "work").exists()


def test_one_other_card_among_the_right_ones_stops_it_too(tmp_path):
    assert _run(tmp_path, ["NVIDIA H100 80GB HBM3", "NVIDIA H200"], "H100").returncode == 3


def test_the_right_cards_let_it_go_on(tmp_path):
    done = _run(tmp_path, ["NVIDIA H100 80GB HBM3"] * 2, "H100")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "work" / "logs").is_dir()
    assert (tmp_path / "h100_x2" / "study_measure.toml").is_file()
