"""A study's microbenchmarks measured for real on lavapipe: several sweeps of one pass."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.studies.measuring import measure_microbenchmarks
from mgpusim.studies.study_file import load_study

pytestmark = pytest.mark.vulkan

STUDY = """name = "tiny"
profile = "lavapipe_2core.toml"
lavapipe_threads_per_core = 1
[microbenchmarks]
rounds = 1
reps = 1
warmup = 0
[microbenchmarks.sweeps]
mesh = [{ width = [32], height = [24], triangles = [200] },
        { width = [32], height = [24], triangles = [300], shape = ["sphere"], cull = ["back"] }]
[microbenchmarks.pairs]
mesh = { width = [32], height = [24], triangles = [300], shape = ["sphere"], cull = ["back"] }
"""


def test_a_pass_with_two_sweeps_gets_both_in_one_table(tmp_path: Path):
    """The lavapipe study measures our torus and vmgpu's culled sphere as two mesh sweeps: one
    mesh table holds both (each row naming its shape and cull), the pair rows too, and its
    machine record keeps both sweeps."""
    shutil.copy("hardware_profiles/lavapipe_2core.toml", tmp_path)
    (tmp_path / "study.toml").write_text(STUDY)
    study = load_study(tmp_path / "study.toml")
    [path] = measure_microbenchmarks(study, tmp_path / "out", lambda _message: None)
    table = pd.read_csv(path)
    seen = set(table[["gpus", "triangles", "shape", "cull"]].itertuples(index=False, name=None))
    assert seen == {(1, 200, "torus", "none"), (1, 300, "sphere", "back"), (2, 300, "sphere", "back")}
    record = json.loads(Path(f"{path}.machine.json").read_text())
    assert [s.get("shape") for s in record["sweeps"]] == [None, ["sphere"]]
    assert record["pairs"]["cull"] == ["back"]
