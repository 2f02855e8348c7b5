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

from mgpusim.vmgpu import campaign, launch, provenance, tables
from mgpusim.vmgpu.__main__ import main, parser
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


def test_the_driver_and_device_switches_default_to_lavapipe_and_simulated_gpus():
    args = parser().parse_args(["--build", "b", "--out", "o"])
    assert args.driver == "lavapipe" and args.real_devices is False
    args = parser().parse_args(["--build", "b", "--out", "o", "--driver", "native",
                                "--real-devices"])
    assert args.driver == "native" and args.real_devices is True
    with pytest.raises(SystemExit):
        parser().parse_args(["--build", "b", "--out", "o", "--driver", "radv"])


def test_real_devices_drop_simulate_mgpu_from_every_config():
    grid = campaign.Grid(("single", "sort-last"), (1, 2), (10_000,), ((64, 48),), simulate=False)
    assert all(not c.simulate for c in grid.configs())
    args = Config("sort-last", 2, 10_000, 64, 48, simulate=False).arguments(Path("/m.obj"))
    assert args == ["-b", "-s", "sort-last", "-c", "2", "-r", "64x48", "-p", "/m.obj"]


def test_lavapipe_sets_its_icd_and_native_leaves_the_drivers_variables(tmp_path, monkeypatch):
    icd = tmp_path / "lvp_icd.json"
    icd.write_text("{}")
    monkeypatch.setattr(launch, "LAVAPIPE_ICD", icd)
    monkeypatch.setenv("VK_ICD_FILENAMES", "/mine/nvidia_icd.json")
    monkeypatch.setenv("VK_DRIVER_FILES", "/mine/nvidia_icd.json")
    lavapipe = launch.environment(":5", 10, tmp_path)
    assert lavapipe["VK_ICD_FILENAMES"] == str(icd)
    native = launch.environment(":5", 10, tmp_path, driver="native")
    assert native["VK_ICD_FILENAMES"] == "/mine/nvidia_icd.json"
    assert native["VK_DRIVER_FILES"] == "/mine/nvidia_icd.json"
    assert native["DISPLAY"] == ":5" and native["VMGPU_EXIT_AFTER_FRAMES"] == "10"
    with pytest.raises(ValueError, match="driver must be one of"):
        launch.environment(":5", 10, tmp_path, driver="radv")


@pytest.mark.parametrize(("driver", "simulate", "icd", "flag"), [
    ("lavapipe", True, "lavapipe", "--simulate-mgpu"),
    ("native", False, "/mine/nvidia_icd.json", ""),
])
def test_the_switches_reach_vmgpus_command_line_and_environment(tmp_path, monkeypatch, driver,
                                                                 simulate, icd, flag):
    """A fake vmgpu that writes down its arguments and Vulkan driver variable, then fails."""
    lvp = tmp_path / "lvp_icd.json"
    lvp.write_text("{}")
    monkeypatch.setattr(launch, "LAVAPIPE_ICD", lvp)
    monkeypatch.setenv("VK_ICD_FILENAMES", "/mine/nvidia_icd.json")
    seen = tmp_path / "seen.txt"
    build = check_build(fake_build(tmp_path / "build", f'echo "$@" > {seen}; '
                                                       f'echo "$VK_ICD_FILENAMES" >> {seen}; exit 3'))
    grid = campaign.Grid(("sort-first",), (2,), (10_000,), ((64, 48),), simulate=simulate)
    settings = campaign.Settings(frames=5, warmup=1, repeats=1, timeout_s=30, driver=driver)
    with pytest.raises(RunFailedError, match="exited with status 3"):
        campaign.run_campaign(build, grid, settings, ":99999", tmp_path / "m", NoProbe(),
                              progress=lambda _: None)
    argv, env_icd = seen.read_text().splitlines()
    assert argv.startswith("-b -s sort-first -c 2 ")
    assert ("--simulate-mgpu" in argv.split()) == bool(flag)
    assert env_icd == (str(lvp) if icd == "lavapipe" else icd)


def summary_tables() -> tuple[pd.DataFrame, pd.DataFrame]:
    runs = pd.DataFrame({"strategy": ["single"], "gpus": [1], "triangles": [10_000],
                         "width": [64], "height": [48], "half": ["calibration"],
                         "median_ms": [1.0], "iqr_ms": [0.1], "stalls": [0]})
    return runs, pd.DataFrame({"run": [0], "period_ms": [1.0]})


def test_the_native_provenance_records_nvidia_smis_card_and_driver(tmp_path, monkeypatch):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    smi = bin_dir / "nvidia-smi"
    smi.write_text('#!/bin/sh\nif [ "$1" = -L ]; then echo "GPU 0: NVIDIA H200 (UUID: GPU-1)"; '
                   'else echo "name, driver_version"; echo "NVIDIA H200, 580.159.04"; fi\n')
    smi.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    build = check_build(fake_build(tmp_path / "build", "exit 0"))
    grid = campaign.Grid(("single",), (1,), (10_000,), ((64, 48),), simulate=False)
    settings = campaign.Settings(frames=5, warmup=1, repeats=1, timeout_s=30, driver="native")
    ctx = provenance.context(build, None, "none", ["python", "-m", "mgpusim.vmgpu"], "native")
    assert "NVIDIA H200, 580.159.04" in ctx.gpu_report and "GPU 0: NVIDIA H200" in ctx.gpu_report
    doc = provenance.text(ctx, grid, settings, *summary_tables(), {}, [])
    assert doc.startswith("# vmgpu on native: provenance")
    assert "NVIDIA H200, 580.159.04" in doc and "no `--simulate-mgpu`" in doc
    lavapipe = provenance.context(build, None, "none", ["x"])
    assert lavapipe.gpu_report == ""
    doc = provenance.text(lavapipe, campaign.Grid(("single",), (1,), (10_000,), ((64, 48),)),
                          campaign.Settings(frames=5, warmup=1, repeats=1, timeout_s=30),
                          *summary_tables(), {}, [])
    assert doc.startswith("# vmgpu on lavapipe") and "nvidia-smi" not in doc
    assert "lavapipe, simulated GPUs (`--simulate-mgpu`" in doc


def test_nvidia_smi_missing_is_said_in_the_report(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    assert provenance.nvidia_smi().startswith("no nvidia-smi report")
