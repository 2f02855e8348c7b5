"""The vmgpu measuring command: its grid, halves and interleaved order, and its refusals: a folder
that is not a vmgpu build, an executable that prints nothing, exits 1 or crashes -> one clear
error and no table. (No test fakes a successful vmgpu run; the one that runs the real vmgpu needs
VMGPU_BUILD set to a build folder.)"""
from __future__ import annotations

import os
import shutil
import stat
from itertools import pairwise
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.vmgpu import campaign, tables
from mgpusim.vmgpu.__main__ import main
from mgpusim.vmgpu.build_folder import check_build
from mgpusim.vmgpu.failures import NotABuildError, RunFailedError, VmgpuMeasureError
from mgpusim.vmgpu.launch import Config
from mgpusim.vmgpu.speed import NoProbe, find_module

needs_xvfb = pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (package xvfb)")
SMALL = ["--strategies", "single", "--triangles", "10000", "--resolutions", "64x48",
         "--frames", "5", "--warmup", "1", "--repeats", "1", "--no-probe"]


def fake_build(folder: Path, script: str | None) -> Path:
    """A folder shaped like a build (spv/ with the shaders' names) whose 'vmgpu' is `script`."""
    (folder / "spv").mkdir(parents=True)
    for name in ("basic.vert.spv", "basic.frag.spv"):
        (folder / "spv" / name).write_bytes(b"")
    if script is not None:
        exe = folder / "vmgpu"
        exe.write_text("#!/bin/sh\n" + script + "\n")
        exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return folder


def run_main(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(args)
    return code, capsys.readouterr().err


def no_table(out: Path) -> bool:
    return not out.exists() or not [p for p in out.iterdir() if p.name in tables.FILES]


def test_an_empty_folder_is_not_a_build(tmp_path, capsys):
    out = tmp_path / "out"
    code, err = run_main(["--build", str(tmp_path), "--out", str(out), *SMALL], capsys)
    assert code == 2
    assert f"error: {tmp_path} is not a vmgpu build folder: it has no executable 'vmgpu'" in err
    assert err.count("error:") == 1 and "Traceback" not in err
    assert no_table(out)


def test_a_missing_folder_or_shaders_are_not_a_build(tmp_path):
    with pytest.raises(NotABuildError, match="no such folder"):
        check_build(tmp_path / "nowhere")
    build = fake_build(tmp_path / "b", "exit 0")
    (build / "spv" / "basic.frag.spv").unlink()
    with pytest.raises(NotABuildError, match="spv/ lacks basic.frag.spv"):
        check_build(build)


def test_a_vmgpu_that_cannot_be_executed_is_not_a_build(tmp_path):
    build = fake_build(tmp_path / "b", None)
    (build / "vmgpu").write_text("not a program")
    with pytest.raises(NotABuildError, match="no executable 'vmgpu'"):
        check_build(build)


@needs_xvfb
@pytest.mark.parametrize(("script", "reason"), [
    ("exit 0", "it printed no frame times"),
    ("echo 'GPUs:'; exit 1", "it exited with status 1"),
    ("kill -SEGV $$", "it was killed by SIGSEGV"),
])
def test_a_failing_vmgpu_is_one_clear_error_and_no_table(tmp_path, capsys, script, reason):
    build = fake_build(tmp_path / "build", script)
    out = tmp_path / "out"
    code, err = run_main(["--build", str(build), "--out", str(out), "--mesh-dir",
                          str(tmp_path / "meshes"), *SMALL], capsys)
    assert code == 2
    assert f"error: vmgpu run 1/1 (single-x1-10000-64x48, repeat 1) failed: {reason}" in err
    assert "Traceback" not in err
    assert no_table(out)
    assert not any(p.name.endswith(".tmp") for p in tmp_path.rglob("*"))


def test_a_failed_run_ends_the_campaign_without_rows(tmp_path):
    """Without Xvfb: the campaign itself, on a display the fake never opens."""
    build = check_build(fake_build(tmp_path / "build", "echo starting; exit 3"))
    grid = campaign.Grid(("single",), (1,), (10_000,), ((64, 48),))
    settings = campaign.Settings(frames=5, warmup=1, repeats=2, timeout_s=30)
    with pytest.raises(RunFailedError, match="exited with status 3") as err:
        campaign.run_campaign(build, grid, settings, ":99999", tmp_path / "m", NoProbe(),
                              progress=lambda _: None)
    assert "starting" in err.value.tail


def test_a_vmgpu_that_hangs_is_killed_at_the_timeout(tmp_path):
    build = check_build(fake_build(tmp_path / "build", "sleep 30"))
    grid = campaign.Grid(("single",), (1,), (10_000,), ((64, 48),))
    settings = campaign.Settings(frames=5, warmup=1, repeats=1, timeout_s=0.5)
    with pytest.raises(RunFailedError, match=r"did not finish 5 frames in 0.5 s \(killed\)"):
        campaign.run_campaign(build, grid, settings, ":99999", tmp_path / "m", NoProbe(),
                              progress=lambda _: None)


def test_an_out_folder_holding_a_measurement_is_refused(tmp_path, capsys):
    build = fake_build(tmp_path / "build", "exit 0")
    out = tmp_path / "out"
    out.mkdir()
    (out / tables.RUNS).write_bytes(b"x")
    code, err = run_main(["--build", str(build), "--out", str(out), *SMALL], capsys)
    assert code == 2 and "already holds a measurement (runs.parquet)" in err


@pytest.mark.parametrize("bad", [["--frames", "5", "--warmup", "5"], ["--gpus", "0"],
                                 ["--patch", "/nonexistent.patch"], ["--repeats", "0"]])
def test_bad_options_are_one_clear_error(tmp_path, capsys, bad):
    build = fake_build(tmp_path / "build", "exit 0")
    code, err = run_main(["--build", str(build), "--out", str(tmp_path / "o"), *SMALL, *bad], capsys)
    assert code == 2 and err.startswith("error: ")


def test_a_grid_of_only_split_strategies_on_one_gpu_has_nothing_to_run():
    grid = campaign.Grid(("sort-first", "sort-last"), (1,), (10_000,), ((64, 48),))
    with pytest.raises(VmgpuMeasureError, match="no configuration to run"):
        grid.configs()


def default_grid() -> campaign.Grid:
    return campaign.Grid(("single", "sort-first", "sort-last"), (1, 2, 3, 4), (100_000, 1_000_000),
                         ((640, 480), (1024, 768)))


def test_the_grid_runs_single_on_one_gpu_and_the_split_strategies_on_two_or_more():
    configs = default_grid().configs()
    assert len(configs) == (1 + 3 + 3) * 2 * 2
    assert {c.gpus for c in configs if c.strategy == "single"} == {1}
    assert {c.gpus for c in configs if c.strategy != "single"} == {2, 3, 4}
    assert len({c.key for c in configs}) == len(configs)


def test_the_halves_are_a_checkerboard_over_triangles_and_resolution():
    grid = default_grid()
    half = {(c.triangles, c.width): grid.half(c) for c in grid.configs()}
    assert half == {(100_000, 640): "calibration", (100_000, 1024): "held-out",
                    (1_000_000, 640): "held-out", (1_000_000, 1024): "calibration"}
    for strategy, gpus in [("single", 1), ("sort-first", 3), ("sort-last", 4)]:
        mine = {grid.half(c) for c in grid.configs() if (c.strategy, c.gpus) == (strategy, gpus)}
        assert mine == {"calibration", "held-out"}


def test_the_repeats_are_interleaved_rounds():
    configs = default_grid().configs()
    order = campaign.schedule(configs, repeats=3, seed=0)
    assert len(order) == 3 * len(configs)
    for r in range(3):
        round_ = [c for rep, c in order if rep == r]
        assert sorted(c.key for c in round_) == sorted(c.key for c in configs)
    assert all(a[1] != b[1] for a, b in pairwise(order))  # never the same twice in a row
    assert campaign.schedule(configs, 3, seed=0) == order  # the seed fixes it
    assert [c for _, c in order[:len(configs)]] != configs  # shuffled, not the grid's own order


def test_a_config_asks_vmgpu_for_basic_mode_and_simulated_gpus():
    args = Config("sort-last", 3, 100_000, 640, 480).arguments(Path("/m.obj"))
    assert args == ["-b", "-s", "sort-last", "-c", "3", "--simulate-mgpu", "-r", "640x480",
                    "-p", "/m.obj"]


def test_the_projects_speed_probe_is_found_where_it_lives():
    module = find_module()
    assert module.__name__.startswith("mgpusim.") and hasattr(module, "Prober")


def test_tables_are_written_through_temporary_files(tmp_path):
    frame = pd.DataFrame({"run": [0], "x": [1.5]})
    tables.write_all(tmp_path / "o", frame, frame, "# p\n")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == sorted(tables.FILES)
    assert pd.read_parquet(tmp_path / "o" / tables.RUNS).equals(frame)


@pytest.mark.skipif(not os.environ.get("VMGPU_BUILD"), reason="set VMGPU_BUILD to a vmgpu build")
@needs_xvfb
def test_the_real_vmgpu_measures_one_small_grid(tmp_path):
    out = tmp_path / "out"
    assert main(["--build", os.environ["VMGPU_BUILD"], "--out", str(out), "--strategies",
                 "single", "sort-last", "--gpus", "1", "2", "--triangles", "10000",
                 "--resolutions", "160x120", "--frames", "30", "--warmup", "5", "--repeats",
                 "2", "--mesh-dir", str(tmp_path / "m")]) == 0
    runs = pd.read_parquet(out / tables.RUNS)
    assert len(runs) == 4 and (runs["median_ms"] > 0).all()
    assert len(pd.read_parquet(out / tables.FRAMES)) == 4 * 30
    assert "vmgpu commit" in (out / tables.PROVENANCE).read_text()
