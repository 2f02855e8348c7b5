"""`mgpusim sweep`: the grid's product as one table, bad points as rows, resume after SIGKILL,
the Dask path, and --fidelity checked once and passed to every point."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

import mgpusim
from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.sweeps import grid as sweeps

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "sort_first_tc1.toml"


def test_parse_grid_and_points():
    grid = sweeps.parse_grid(["schedule.gpus=1,2,3", "scene.width=1024, 1920", "schedule.name=afr"])
    assert grid == {"schedule.gpus": [1, 2, 3], "scene.width": [1024, 1920], "schedule.name": ["afr"]}
    points = sweeps.grid_points(grid, {"experiment": "x"})
    assert [p.keys for p in points[:3]] == [
        {"schedule.gpus": 1, "scene.width": 1024, "schedule.name": "afr"},
        {"schedule.gpus": 1, "scene.width": 1920, "schedule.name": "afr"},
        {"schedule.gpus": 2, "scene.width": 1024, "schedule.name": "afr"}]
    assert len({p.id for p in points}) == 6
    assert [p.id for p in sweeps.grid_points(grid, {"experiment": "x"})] == [p.id for p in points]
    assert points[0].id != sweeps.grid_points(grid, {"experiment": "y"})[0].id  # other file, other point
    for bad in (["schedule.gpus"], ["=1,2"], ["schedule.gpus="], ["a=1", "a=2"], []):
        with pytest.raises(InputError, match="--grid"):
            sweeps.parse_grid(bad)


def test_flatten_summary():
    assert sweeps.flatten({"a": 1, "u": {"gpu0.graphics": 0.5}, "w": [2, 3], "e": {}}) == {
        "a": 1, "u.gpu0.graphics": 0.5, "w.0": 2, "w.1": 3}


def test_sweep_command_writes_table_plot_and_error_rows(tmp_path, capsys):
    out = tmp_path / "sw"
    rc = main(["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1,2,4", "--grid", "scene.width=512,1024",
               "--set", "schedule.frames=20", "--workers", "1", "--no-progress", "--out", str(out)])
    assert rc == 0
    df = pd.read_parquet(out / "sweep.parquet")
    assert len(df) == 6 and list(df["point"]) == list(range(6))
    assert list(df.columns[:4]) == ["point", "schedule.gpus", "scene.width", "error"]
    bad = df[df["schedule.gpus"] == 4]
    assert len(bad) == 2 and bad["error"].str.contains("asks for 4 GPUs").all()  # TC1 has 3
    good = df[df["error"].isna()]
    assert good["frame_time_ms"].notna().all() and (good["frames"] == 20).all()
    assert {"utilization.gpu0.graphics", "utilization.gpu1.d2h", "window_ns.0", "effects.link_model",
            "memory.gpu0.used_bytes"} <= set(df.columns)
    two = good[good["schedule.gpus"] == 2].set_index("scene.width")["frame_time_ms"]
    one = good[good["schedule.gpus"] == 1].set_index("scene.width")["frame_time_ms"]
    assert (two < one).all()  # two GPUs beat one on the fragment-loop benchmark
    assert (out / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    spec = json.loads((out / "sweep.json").read_text())
    assert spec["points"] == 6 and spec["failed"] == 2 and spec["grid"]["schedule.gpus"] == [1, 2, 4]
    text = capsys.readouterr().out
    assert "6 points" in text and "2 failed" in text


def test_python_api_without_a_folder_matches_simulate():
    df = mgpusim.sweep(EXPERIMENT, {"schedule.gpus": [1, 3]}, overrides={"schedule.frames": 15},
                       workers=1, progress=False)
    exp = mgpusim.load_experiment(EXPERIMENT, {"schedule.gpus": 3, "schedule.frames": 15})
    assert df.loc[1, "frame_time_ms"] == mgpusim.simulate(exp).summary["frame_time_ms"]


def test_local_processes_give_the_same_table_as_one_process(tmp_path):
    grid = {"schedule.gpus": [1, 2], "scene.height": [384, 768]}
    one = mgpusim.sweep(EXPERIMENT, grid, overrides={"schedule.frames": 15}, workers=1, progress=False)
    two = mgpusim.sweep(EXPERIMENT, grid, tmp_path / "p", overrides={"schedule.frames": 15}, workers=2,
                        progress=False)
    pd.testing.assert_frame_equal(one.drop(columns="wall_s"), two.drop(columns="wall_s"))


def _sweep_cmd(out: Path, workers: int = 1) -> list[str]:
    return [sys.executable, "-m", "mgpusim", "sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1,2,3",
            "--grid", "schedule.frames=300,301,302,303", "--workers", str(workers), "--no-progress",
            "--out", str(out)]


def _running(out: Path) -> list[int]:
    """Processes whose command line names the sweep's folder."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and str(out).encode() in (proc / "cmdline").read_bytes():
                pids.append(int(proc.name))
        except OSError:
            continue
    return pids


def _saved(out: Path) -> dict[str, tuple[int, bytes]]:
    """The sweep's saved point files (points run one by one are saved a few at a time)."""
    if not (out / "points").is_dir():
        return {}
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "points").glob("single-*.parquet")}


def _saved_points(out: Path) -> pd.DataFrame:
    """Every saved point's row (column `id`, error, wall_s, the summary's columns)."""
    files = sorted((out / "points").glob("single-*.parquet")) if (out / "points").is_dir() else []
    return pd.concat([pd.read_parquet(f) for f in files], ignore_index=True) if files else pd.DataFrame({"id": []})


@pytest.mark.parametrize("workers", [1, 2])
def test_resume_after_sigkill_loses_and_recomputes_nothing(tmp_path, workers):
    out = tmp_path / "sw"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MGPUSIM_SWEEP_SAVE_S": "0"}  # each point saved as it ends
    proc = subprocess.Popen(_sweep_cmd(out, workers), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while len(_saved_points(out)) < 2:
        assert proc.poll() is None, "the sweep finished before it could be killed: make it longer"
        assert time.monotonic() < deadline
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = _saved(out)
    deadline = time.monotonic() + 10
    while _running(out):  # the killed sweep's pool workers leave with it
        assert time.monotonic() < deadline, "orphaned sweep workers"
        time.sleep(0.1)
    kept = _saved_points(out)
    assert 2 <= len(kept) < 12 and not (out / "sweep.parquet").exists()
    assert (kept["frame_time_ms"] > 0).all()

    done = subprocess.run(_sweep_cmd(out, workers), env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    after = _saved(out)
    assert {k: after[k] for k in before} == before  # not one finished point was written again
    ids = _saved_points(out)["id"]
    assert len(ids) == 12 and ids.is_unique
    df = pd.read_parquet(out / "sweep.parquet")
    assert len(df) == 12 and df["error"].isna().all()
    assert sorted(zip(df["schedule.gpus"], df["schedule.frames"])) == [
        (g, f) for g in (1, 2, 3) for f in (300, 301, 302, 303)]
    assert (df["frames"] == df["schedule.frames"]).all()


def test_killed_while_finishing_never_leaves_a_corrupt_table(tmp_path):
    out = tmp_path / "sw"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    assert subprocess.run(_sweep_cmd(out), env=env, capture_output=True, timeout=120).returncode == 0
    for delay in (1.1, 1.5, 1.9):  # all points saved: after ~1 s of imports, each run is finishing
        proc = subprocess.Popen(_sweep_cmd(out), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        assert len(pd.read_parquet(out / "sweep.parquet")) == 12
        assert json.loads((out / "sweep.json").read_text())["points"] == 12
    assert subprocess.run(_sweep_cmd(out), env=env, capture_output=True, timeout=120).returncode == 0
    assert not list(out.rglob(".*.tmp"))  # a killed run's temporary files are cleaned up


def test_dask_local_cluster_runs_the_points(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        rc = main(["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1,2,5", "--set", "schedule.frames=15",
                   "--dask", cluster.scheduler_address, "--no-progress", "--out", str(tmp_path / "d")])
    assert rc == 0
    df = pd.read_parquet(tmp_path / "d" / "sweep.parquet")
    local = mgpusim.sweep(EXPERIMENT, {"schedule.gpus": [1, 2, 5]}, overrides={"schedule.frames": 15},
                          workers=1, progress=False)
    pd.testing.assert_frame_equal(df.drop(columns="wall_s"), local.drop(columns="wall_s"))
    assert df["error"].notna().tolist() == [False, False, True]


def test_bad_workers_is_one_error_before_any_file(tmp_path, capsys):
    rc = main(["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1", "--workers", "0", "--out", str(tmp_path / "w")])
    assert rc == 2 and "--workers" in capsys.readouterr().err and not (tmp_path / "w").exists()


def test_unreachable_dask_scheduler_is_one_error(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(sweeps, "DASK_CONNECT_TIMEOUT", "1s")
    rc = main(["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1", "--dask", "tcp://127.0.0.1:9",
               "--no-progress", "--out", str(tmp_path / "d")])
    assert rc == 2 and "--dask" in capsys.readouterr().err


def test_fidelity_is_checked_once_then_passed_to_every_point(tmp_path, monkeypatch, capsys):
    seen = []

    def with_fidelity(exp, record_trace=True, fidelity="full"):
        seen.append(fidelity)
        return mgpusim.Result({"frame_time_ms": 2.0}, pd.DataFrame(), pd.DataFrame())

    monkeypatch.setattr(sweeps, "simulate", with_fidelity)
    args = ["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1,2", "--workers", "1", "--no-progress"]
    assert main([*args, "--fidelity", "fast", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fidelity" in err[0] and "analytic" in err[0]
    assert not (tmp_path / "a" / "sweep.parquet").exists() and seen == []
    assert main([*args, "--fidelity", "queues", "--out", str(tmp_path / "c")]) == 0  # (analytic: lanes)
    assert seen == ["queues", "queues"]
    assert pd.read_parquet(tmp_path / "c" / "sweep.parquet")["frame_time_ms"].tolist() == [2.0, 2.0]


def test_sweep_plot_lines_or_heatmap_by_number_of_keys():
    from matplotlib.figure import Figure

    from mgpusim.io.plot import draw_sweep

    combos = [(a, b, c) for a in (1, 2, 3) for b in (5, 6) for c in ("x", "y")]
    rows = [{"point": i, "a": a, "b": b, "c": c, "error": None if a < 3 else "bad",
             "frame_time_ms": a * 10.0 + b + (c == "y")} for i, (a, b, c) in enumerate(combos)]
    table = pd.DataFrame(rows)
    one = Figure().subplots()
    draw_sweep(one, table[(table.b == 5) & (table.c == "x")], ["a"])
    (line,) = one.get_lines()
    assert list(line.get_ydata()) == [15.0, 25.0]  # the failed point is left out
    two = Figure().subplots()
    draw_sweep(two, table[table.c == "x"], ["a", "b"])
    assert len(two.get_images()) == 1 and {"failed"} <= {t.get_text() for t in two.texts}
    three = Figure().subplots()
    draw_sweep(three, table, ["a", "b", "c"])
    assert len(three.get_lines()) == 4 and len(three.get_legend().get_texts()) == 4


# ----- one folder, two sweeps -------------------------------------------------------------
def _quick(out: Path) -> list[str]:
    return ["sweep", str(EXPERIMENT), "--grid", "schedule.gpus=1,2", "--set", "schedule.frames=20",
            "--workers", "1", "--no-progress", "--out", str(out)]


def test_a_sweep_into_a_folder_another_sweep_holds_is_refused_and_touches_nothing(tmp_path, capsys):
    from mgpusim.sweeps.store import PointStore
    out = tmp_path / "sw"
    with PointStore(out):  # as a running sweep holds it
        assert main(_quick(out)) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "another sweep" in err[0] and f"process {os.getpid()}" in err[0]
        assert not list((out / "points").iterdir()) and not (out / "sweep.parquet").exists()
    assert main(_quick(out)) == 0  # released at the end of the holder's `with`
    assert len(_saved_points(out)) == 2


def test_the_lock_ends_with_a_sweep_killed_by_sigkill(tmp_path):
    """A process holding the folder (as a sweep does) is killed with SIGKILL: the system drops
    its lock, and the next sweep runs; while it lived, a sweep was refused."""
    out = tmp_path / "sw"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from mgpusim.sweeps.store import PointStore; s = PointStore(Path(sys.argv[1])).__enter__(); "
         "print('held', flush=True); time.sleep(600)", str(out)], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        refused = subprocess.run([sys.executable, "-m", "mgpusim", *_quick(out)], env=env,
                                 capture_output=True, text=True, timeout=120)
        assert refused.returncode == 2 and f"process {holder.pid}" in refused.stderr
    finally:
        holder.kill()
        holder.wait()
    done = subprocess.run([sys.executable, "-m", "mgpusim", *_quick(out)], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_two_sweeps_started_at_once_into_one_folder_never_corrupt_it(tmp_path):
    """Both start together: each either runs whole or is refused with one line (exit 2); the
    folder is then complete and consistent, and a third run recomputes nothing."""
    out = tmp_path / "sw"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "mgpusim", *_sweep_cmd(out)[3:]]
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = [(p.wait(timeout=180), p.stderr.read()) for p in procs]
    for p in procs:
        p.stdout.close()
        p.stderr.close()
    codes = sorted(code for code, _ in results)
    assert codes in ([0, 0], [0, 2]), results
    for code, err in results:
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and "another sweep" in err
    assert len(pd.read_parquet(out / "sweep.parquet")) == 12
    saved = _saved(out)
    points = _saved_points(out)
    assert len(points) == 12 and points["id"].is_unique and points["error"].isna().all()
    assert not list(out.rglob(".*.tmp"))
    again = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and _saved(out) == saved
