"""The sweep's fast paths: every key at the analytic level as lanes (scene, schedule and profile
keys as groups of their own, a profile key that is not a pass cost beside pass-cost lanes),
local worker processes giving the same table as one, points run one by one saved a batch file
at a time (and resumed from them), and the grid's point ids as before."""
from __future__ import annotations

import hashlib
import json
import random
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.sweeps import grid as sweeps
from mgpusim.sweeps import lanes
from tests.test_sweep_lanes import _files, _per_point, _sweep, assert_same_table

ROOT = Path(__file__).resolve().parents[1]
EXP = ROOT / "experiments"
SPEED = "profile.gpus.*.speed"


def test_scene_and_schedule_keys_run_as_lanes_and_give_the_per_point_table(tmp_path, monkeypatch):
    grid = {"scene.width": [640, 1024, 1920], "scene.height": [480, 768], "schedule.gpus": [1, 3]}
    df = _sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a")
    assert _files(tmp_path / "a") == (12, 0)
    assert_same_table(df, _per_point(monkeypatch, EXP / "sort_first_tc1.toml", grid, tmp_path / "b"))


@pytest.mark.parametrize("experiment", ["sort_last_tc1.toml", "afr_tc1.toml", "xr_quest3_pcie4.toml",
                                        "pipelining_miniengine_pcie3x8.toml"])
def test_a_profile_group_key_beside_pass_cost_lanes_gives_the_per_point_table(experiment, tmp_path, monkeypatch):
    grid = {"profile.gpus.*.task_gap_ns": [0, 2000], "scene.width": [800, 1024], SPEED: [0.5, 1.0, 2.0]}
    plan = lanes.plan(EXP / experiment, grid, {"schedule.frames": 24})
    assert plan.lane_keys == [SPEED]
    df = _sweep(EXP / experiment, grid, tmp_path / "a")
    assert _files(tmp_path / "a") == (12, 0) and df["error"].isna().all()
    assert_same_table(df, _per_point(monkeypatch, EXP / experiment, grid, tmp_path / "b"))


def test_the_template_is_checked_and_every_group_works_out_its_own_fields(tmp_path, monkeypatch):
    """Groups of one structure but other memory and effects: each row has its own group's."""
    grid = {"profile.gpus.*.memory_bytes": [4 << 30, 8 << 30], "profile.host.submit_ns": [0, 500], SPEED: [1.0, 2.0]}
    df = _sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a")
    assert df["memory.gpu0.capacity_bytes"].nunique() == 2
    assert_same_table(df, _per_point(monkeypatch, EXP / "sort_first_tc1.toml", grid, tmp_path / "b"))


def test_local_workers_give_the_same_lanes_table_as_one_process(tmp_path):
    grid = {"scene.width": [640, 800, 1024, 1280], SPEED: [0.5, 1.0, 2.0],
            "profile.host.memcpy_thread_gbps": [4.0, 6.0, 9.0]}
    kw = {"overrides": {"schedule.frames": 24}, "fidelity": "analytic", "progress": False}
    one = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "one", workers=1, **kw)
    two = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "two", workers=2, **kw)
    pd.testing.assert_frame_equal(one.drop(columns="wall_s"), two.drop(columns="wall_s"))


def test_points_run_one_by_one_are_saved_a_batch_at_a_time_and_resumed(tmp_path, monkeypatch):
    monkeypatch.setenv("MGPUSIM_SWEEP_SAVE_S", "0")
    grid = {"schedule.gpus": [1, 2], "scene.width": [800, 1024]}
    kw = {"overrides": {"schedule.frames": 20}, "progress": False, "workers": 1}
    whole = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a", **kw)
    files = sorted((tmp_path / "a" / "points").glob("single-*.parquet"))
    assert len(files) == 4 and not list((tmp_path / "a" / "points").glob("*.json"))
    files[2].unlink()  # as if killed before its last points were saved
    (tmp_path / "a" / "sweep.parquet").unlink()
    ran = []
    real = sweeps.run_point
    monkeypatch.setattr(sweeps, "run_point", lambda *a: ran.append(a) or real(*a))
    again = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a", **kw)
    assert len(ran) == 1
    pd.testing.assert_frame_equal(again.drop(columns="wall_s"), whole.drop(columns="wall_s"))


def test_an_older_folders_point_files_are_still_read(tmp_path):
    grid = {"schedule.gpus": [1, 2]}
    kw = {"overrides": {"schedule.frames": 20}, "progress": False, "workers": 1}
    whole = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a", **kw)
    points = tmp_path / "a" / "points"
    (saved,) = points.glob("single-*.parquet")
    rows = pd.read_parquet(saved)
    identity = sweeps.point_identity(EXP / "sort_first_tc1.toml", grid, kw["overrides"], "full")
    for p in sweeps.grid_points(grid, identity):  # one JSON file per point, as sweeps wrote them
        record = whole.iloc[p.index]
        summary = {k: (v.item() if hasattr(v, "item") else v) for k, v in rows[rows["id"] == p.id].iloc[0].items()
                   if k not in ("id", "error", "wall_s") and v == v}
        (points / f"{p.id}.json").write_text(json.dumps({"keys": p.keys, "summary": summary, "error": None,
                                                         "wall_s": float(record["wall_s"])}))
    saved.unlink()
    (tmp_path / "a" / "sweep.parquet").unlink()
    again = sweeps.sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a", **kw)
    assert not list(points.glob("single-*.parquet"))  # nothing ran again
    assert again["frame_time_ms"].tolist() == whole["frame_time_ms"].tolist()


def test_point_ids_are_the_hash_of_the_point_and_the_identity():
    rng = random.Random(7)
    for _ in range(20):
        keys = rng.sample(["scene.width", "a.b", "zeta", "profile.gpus.*.speed", "schedule.gpus", "m"],
                          rng.randint(1, 4))
        grid = {k: rng.sample([1, 2.5, "x", True, [1, 2], {"q": 1}, 7, None], rng.randint(1, 3)) for k in keys}
        identity = rng.choice([{"experiment": "e", "fidelity": "full", "overrides": {"a": 1}},
                               {"experiment": "e"}, {"zz": 1}, {}])
        points = sweeps.grid_points(grid, identity)
        import itertools
        want = list(itertools.product(*grid.values()))
        assert [tuple(p.keys.values()) for p in points] == want
        assert [p.index for p in points] == list(range(len(want)))
        for p in points:
            blob = json.dumps({**identity, "point": p.keys}, sort_keys=True, default=str)
            assert p.id == hashlib.sha256(blob.encode()).hexdigest()[:20]
