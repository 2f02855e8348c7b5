"""Two logical GPUs on one physical device (`--gpus-per-device 2`): the run records where each
ran, and `validate` compares it only with a profile that says they share it."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from mgpusim.cli import main

pytestmark = pytest.mark.vulkan

EXP = str(Path(__file__).resolve().parents[2] / "experiments" / "h100" / "particles.toml")
TINY = ["--set", "scene.width=32", "--set", "scene.height=16", "--set", "schedule.particles=256",
        "--set", "schedule.frames=5", "--set", "schedule.warmup_frames=1",
        "--set", 'scene.passes=[{name="shadow",kind="fragment_loop",iterations=10},'
                 '{name="geometry",kind="fragment_loop",iterations=10}]',
        "--set", "schedule.gpus=2", "--set", "schedule.particle_gpu=1", "--set", "profile.gpu_count=2"]


def test_two_logical_gpus_on_one_device(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", EXP, *TINY, "--gpus-per-device", "2", "--prewarm", "2", "--out", str(out)]) == 0
    machine = json.loads((out / "machine.json").read_text())
    assert [g["physical_index"] for g in machine["gpus"]] == [0, 0]
    capsys.readouterr()
    # the H100 profile gives each logical GPU its own physical GPU: refused, naming the field
    assert main(["validate", EXP, *TINY, "--measured", str(out), "--out", str(tmp_path / "v1")]) != 0
    assert "gpus[1].physical" in capsys.readouterr().err
    shared = [*TINY, "--set", "profile.gpus.0.physical=0"]
    assert main(["validate", EXP, *shared, "--measured", str(out), "--out", str(tmp_path / "v2")]) == 0
    assert "frame_time_error" in json.loads((tmp_path / "v2" / "summary.json").read_text())
