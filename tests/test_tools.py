"""The scripts under tools/ that no other test runs: the advice validation's entry points, the
particle sweep and the device-group listing. Each is loaded from its file as a user runs it."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pandas as pd
import pytest

from mgpusim.schedules.experiment import load_experiment

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "tools"


def _load(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(path.stem + "_tool", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("script", ["lavapipe.py", "h100_x4.py"])
def test_advice_validation_frames_load_on_their_profile(script: str) -> None:
    setup = _load(TOOLS / "advise_validation" / script).SETUP
    assert setup.profile.is_file()
    assert len(setup.frames) == 5
    for frame in setup.frames:
        exp = load_experiment(frame.experiment, frame.capture)
        assert exp.schedule.gpus == 1  # each frame is captured on one GPU, then advised


def test_advice_validation_shell_entry_names_an_existing_script() -> None:
    text = (TOOLS / "advise_validation" / "h100_x4.sh").read_text()
    named = [w.split("=", 1)[1] for w in text.split() if w.startswith("script=")]
    assert named and all((ROOT / n).is_file() for n in named)


def test_particle_sweep_covers_every_count_and_config(tmp_path: Path) -> None:
    out = tmp_path / "particles.csv"
    run = subprocess.run([sys.executable, str(TOOLS / "particles_sweep.py"), "--csv", str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    table = pd.read_csv(out)
    assert len(table) == 8 * 3
    one = table[table.config == "1gpu"].set_index("particles")
    # more particles cost the single GPU more frame time: the sweep varies what it says it does
    assert one.frame_time_ms.loc[1048576] > one.frame_time_ms.loc[256]


@pytest.mark.vulkan
def test_device_groups_lists_lavapipe() -> None:
    run = subprocess.run([sys.executable, str(TOOLS / "nvidia" / "device_groups.py")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stdout.splitlines()
    assert lines[0].endswith("physical-device group(s)") and int(lines[0].split()[0]) >= 1
    assert any("llvmpipe" in line for line in lines[1:])
