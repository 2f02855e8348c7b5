"""The advice validation with real runs on lavapipe: one tiny frame, one round."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.advise.on_hardware import Frame, Setup, validate

pytestmark = pytest.mark.vulkan
ROOT = Path(__file__).resolve().parents[2]


def test_a_tiny_lavapipe_frame_is_captured_advised_and_run(tmp_path: Path) -> None:
    frame = Frame("fragment loop", ROOT / "experiments" / "lavapipe" / "sort_first.toml",
                  {"schedule.gpus": 1, "scene.width": 64, "scene.height": 48,
                   "scene.passes.0.iterations": 50})
    setup = Setup(profile=ROOT / "hardware_profiles" / "lavapipe_2core.toml", frames=(frame,),
                  max_gpus=2, repeats=1, frames_per_run=10, workers=1)
    results = validate(setup, tmp_path, log=lambda _: None)
    measured = pd.read_json(tmp_path / "frames" / "fragment_loop" / "capture1" / "machine.json",
                            typ="series")
    assert "dry_run" not in measured.index  # a real run's machine record
    assert results["measured_ms"].notna().all() and (results["measured_ms"] > 0).all()
    assert len(pd.read_csv(tmp_path / "runs.csv")) == len(results)
