"""`mgpusim sweep --fidelity analytic` as numpy lanes: the same table as point by point (across
schedules), the per-point fallback for keys and schedules lanes cannot express, one file per
batch and an exact resume after SIGKILL, and bad grid keys refused once."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim.cli import main
from mgpusim.sweeps import grid as sweeps
from mgpusim.sweeps import lanes as lanes

ROOT = Path(__file__).resolve().parents[1]
EXP = ROOT / "experiments"
SPEED = "profile.gpus.*.speed"


def _sweep(experiment: Path, grid: dict, out: Path, frames: int = 24, **kw) -> pd.DataFrame:
    return sweeps.sweep(experiment, grid, out, overrides={"schedule.frames": frames}, fidelity="analytic",
                        workers=1, progress=False, **kw)


def _per_point(monkeypatch, experiment: Path, grid: dict, out: Path, frames: int = 24) -> pd.DataFrame:
    with monkeypatch.context() as m:
        m.setenv("MGPUSIM_SWEEP_NO_LANES", "1")
        return _sweep(experiment, grid, out, frames)


def _files(out: Path) -> tuple[int, int]:
    """(points saved from lanes, points saved as run one by one) in a sweep's folder."""
    def rows(prefix: str) -> int:
        return sum(len(pd.read_parquet(f)) for f in (out / "points").glob(f"{prefix}-*.parquet"))
    return rows("batch"), rows("single") + len(list((out / "points").glob("*.json")))


def assert_same_table(a: pd.DataFrame, b: pd.DataFrame) -> None:
    """Same columns and dtypes; integers and text equal; floats within 1e-12 (relative)."""
    assert list(a.columns) == list(b.columns)
    assert dict(a.dtypes) == dict(b.dtypes)
    for col in a.columns:
        if col == "wall_s":
            continue
        x, y = a[col], b[col]
        if pd.api.types.is_float_dtype(x):
            assert np.allclose(x.to_numpy(), y.to_numpy(), rtol=1e-12, atol=0, equal_nan=True), col
        else:
            assert x.astype(str).tolist() == y.astype(str).tolist(), col


CASES = {  # experiment -> a grid of group keys and lane keys
    "sort_first_five_step": ("sort_first_tc1.toml", {
        "schedule.gpus": [2, 3], SPEED: [1.0, 2.5],
        "profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration": [0.0016, 0.004]}),
    "sort_last_five_step": ("sort_last_tc1.toml", {
        "scene.width": [800, 1024], "profile.gpus.0.speed": [0.5, 1.0, 3.0],
        "profile.gpus.1.costs.mesh.fixed_ns": [0, 80000]}),
    "afr": ("afr_tc1.toml", {"profile.gpus.1.speed": [0.25, 1.0, 2.0], "profile.gpus.0.speed": [1.0, 4.0]}),
    "xr": ("xr_quest3_pcie4.toml", {SPEED: [0.5, 1.0, 2.0], "profile.gpus.*.costs.mesh.ns_per_triangle": [0.3, 2.0]}),
    "pipelining": ("pipelining_miniengine_pcie3x8.toml", {SPEED: [0.5, 1.0, 1.5, 3.0]}),
    "particles_h100": ("h100/particles.toml", {SPEED: [0.5, 1.0, 2.0]}),
    # scene, schedule and profile group keys (every group its own program) beside lane keys;
    # 900 GB/s and 5e7 ns lie outside every shipped profile's values (warnings.* columns)
    "scene_schedule_profile": ("sort_first_tc1.toml", {
        "scene.width": [800, 1024], "scene.height": [600, 768], "schedule.gpus": [2, 3],
        "profile.host.memcpy_thread_gbps": [5, 900], SPEED: [1.0, 2.0],
        "profile.gpus.*.costs.fragment_loop.fixed_ns": [0, 5e7]}),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_lanes_give_the_per_point_table(case, tmp_path, monkeypatch):
    experiment, grid = CASES[case]
    vector = _sweep(EXP / experiment, grid, tmp_path / "lanes")
    batches, singles = _files(tmp_path / "lanes")
    assert batches >= 1 and singles == 0  # every point ran as a lane
    assert vector["error"].isna().all()
    assert vector["frame_time_ms"].nunique() > 1  # the lane keys changed the results
    assert_same_table(vector, _per_point(monkeypatch, EXP / experiment, grid, tmp_path / "points"))


def test_integer_fields_are_exact_and_repeats_match(tmp_path, monkeypatch):
    grid = {"schedule.frames_in_flight": [1, 2], SPEED: [0.7, 1.0, 1.3]}
    vector = _sweep(EXP / "h100_x4" / "sort_first.toml", grid, tmp_path / "l", frames=40)
    single = _per_point(monkeypatch, EXP / "h100_x4" / "sort_first.toml", grid, tmp_path / "p", frames=40)
    for col in ("window_ns.0", "window_ns.1", "fast_forward.period_ns", "fast_forward.from_frame"):
        assert vector[col].tolist() == single[col].tolist()
    assert vector["fast_forward.used"].all()  # the state repeats at every point


def test_what_becomes_a_lane_key():
    grid = {"scene.width": [640], SPEED: [1, 2], "profile.gpus.0.costs.fragment_loop.fixed_ns": [0, 9],
            "profile.host.memcpy_threads": [2, 4]}
    path = EXP / "sort_first_tc1.toml"
    p = lanes.plan(path, {k: grid[k] for k in (SPEED, "scene.width")}, {})
    assert p.lane_keys == [SPEED] and p.group_keys == ["scene.width"]
    assert p.coefs[SPEED][1] == {(i, "speed"): 2.0 for i in range(3)}
    clash = lanes.plan(path, {SPEED: [1, 2], "profile.gpus.0.speed": [1, 3]}, {})
    assert clash.lane_keys == [] and "same coefficient" in clash.notes[-1]
    other = lanes.plan(path, grid, {})  # memcpy_threads changes more than pass costs: a group key
    assert other.lane_keys == [SPEED, "profile.gpus.0.costs.fragment_loop.fixed_ns"]
    assert other.group_keys == ["scene.width", "profile.host.memcpy_threads"]
    assert any("memcpy_threads" in n for n in other.notes)
    more = lanes.plan(path, {SPEED: [1, 2], "profile.gpu_count": [3, 4]}, {})  # a 4th GPU: its own costs
    assert more.lane_keys == [] and "which pass costs" in more.notes[-1]
    speeds = lanes.plan(path, {SPEED: [1, 2], "profile.gpus.1.costs.fragment_loop.fixed_ns": [0, 7],
                               "profile.gpus.*.costs.fragment_loop.fixed_ns": [0, 5]}, {})
    assert speeds.lane_keys == [] and "same coefficient" in speeds.notes[-1]
    assert lanes.plan(path, {"profile": ["../hardware_profiles/tc2.toml"], SPEED: [1, 2]}, {}).lane_keys == []


def test_keys_no_lane_expresses_run_as_groups_of_their_own(tmp_path, monkeypatch):
    """memcpy_threads changes more than pass costs: every profile key is then a group key,
    each group one lane (a lane per point), and the table is still the per-point one."""
    grid = {SPEED: [1.0, 2.0], "profile.host.memcpy_threads": [2, 4]}
    df = _sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "a")
    assert _files(tmp_path / "a") == (4, 0)
    assert_same_table(df, _per_point(monkeypatch, EXP / "sort_first_tc1.toml", grid, tmp_path / "b"))


def test_skippable_schedules_and_failing_points_fall_back(tmp_path, monkeypatch):
    skippable = {SPEED: [1.0, 2.0]}
    df = _sweep(EXP / "lavapipe" / "particles.toml", skippable, tmp_path / "s")
    assert _files(tmp_path / "s") == (0, 2) and df["error"].isna().all()
    # lanes whose pass would outlast the time bound run alone and report it; a group whose
    # first point cannot load (4 GPUs on a 3-GPU profile) runs point by point
    grid = {"schedule.gpus": [2, 4], "profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration": [0.0016, 1e3]}
    mixed = _sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "m")
    assert _files(tmp_path / "m") == (1, 3)
    assert mixed["error"].notna().tolist() == [False, True, True, True]
    assert "more than" in mixed.loc[1, "error"] and "GPUs" in mixed.loc[2, "error"]
    assert_same_table(mixed, _per_point(monkeypatch, EXP / "sort_first_tc1.toml", grid, tmp_path / "p"))


def test_a_partial_batch_state_resumes_exactly(tmp_path):
    grid = {"scene.width": [640, 1024, 1920], SPEED: [0.5, 1.0, 2.0, 4.0]}
    whole = _sweep(EXP / "sort_first_tc1.toml", grid, tmp_path / "whole")
    out = tmp_path / "cut"
    _sweep(EXP / "sort_first_tc1.toml", grid, out)
    saved = sorted((out / "points").glob("batch-*.parquet"))
    assert len(saved) == 3  # one batch per width (the host copy's parts differ)
    saved[1].unlink()  # as if killed while writing that batch: its temporary file is left
    (out / "points" / ".batch-x.parquet.123.tmp").write_bytes(b"half")
    (out / "sweep.parquet").unlink()
    ran = []
    real = lanes.run_batch
    lanes.run_batch = lambda batch, plan_: ran.append(sum(len(g.points) for g in batch.groups)) or real(batch, plan_)
    try:
        again = _sweep(EXP / "sort_first_tc1.toml", grid, out)
    finally:
        lanes.run_batch = real
    assert ran == [4]  # only the missing batch's points
    assert not list((out / "points").glob(".*.tmp"))
    assert_same_table(again, whole)
    assert again.drop(columns="wall_s").equals(whole.drop(columns="wall_s"))


def test_sigkill_mid_sweep_then_the_same_command_finishes_exactly(tmp_path):
    values = ",".join(str(0.5 + i / 400) for i in range(1000))
    args = [sys.executable, "-m", "mgpusim", "sweep", str(EXP / "sort_first_tc1.toml"), "--grid",
            "scene.width=640,800,1024,1280,1600,1920", "--grid", f"{SPEED}={values}", "--set",
            "schedule.frames=30", "--fidelity", "analytic", "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = tmp_path / "killed"
    proc = subprocess.Popen([*args, "--out", str(out)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list((out / "points").glob("batch-*.parquet")) if (out / "points").exists() else True:
        assert time.monotonic() < deadline and proc.poll() is None, "no batch was saved"
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "sweep.parquet").exists()
    done = sum(len(pd.read_parquet(b)) for b in (out / "points").glob("batch-*.parquet"))
    subprocess.run([*args, "--out", str(out)], env=env, check=True, capture_output=True)
    subprocess.run([*args, "--out", str(tmp_path / "whole")], env=env, check=True, capture_output=True)
    assert 0 < done < 6000  # killed between two batches
    again = pd.read_parquet(out / "sweep.parquet")
    whole = pd.read_parquet(tmp_path / "whole" / "sweep.parquet")
    assert len(again) == 6000 and again.drop(columns="wall_s").equals(whole.drop(columns="wall_s"))
    rows = sum(len(pd.read_parquet(b)) for b in (out / "points").glob("batch-*.parquet"))
    assert rows == 6000 and _files(out)[1] == 0  # every point saved once: none ran twice


@pytest.mark.parametrize("key", ["profile.gpus.*.sped", "scene.widht", "profile.gpus.7.speed"])
def test_a_bad_grid_key_is_one_error(key, tmp_path, capsys):
    rc = main(["sweep", str(EXP / "sort_first_tc1.toml"), "--grid", f"{key}=1,2", "--grid", f"{SPEED}=1,2",
               "--fidelity", "analytic", "--no-progress", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and key in err[0]
    assert not (tmp_path / "o" / "points").exists() or not os.listdir(tmp_path / "o" / "points")


def test_a_big_grid_plots_one_heatmap():
    from matplotlib.figure import Figure

    from mgpusim.io.plot import draw_sweep

    a, b, c = np.meshgrid(np.arange(30), np.arange(20), np.arange(15), indexing="ij")
    table = pd.DataFrame({"a": a.ravel(), "b": b.ravel(), "c": c.ravel(), "error": None})
    table["frame_time_ms"] = table["a"] + 10.0 * table["b"] + table["c"]
    ax = Figure().subplots()
    draw_sweep(ax, table, ["a", "b", "c"])
    (image,) = ax.get_images()
    grid = image.get_array()
    assert grid.shape == (30, 20) and grid[3, 2] == pytest.approx(3 + 20 + 7.0)  # mean over c
    assert not ax.get_lines() and not ax.texts  # 600 cells: no per-cell labels
