"""Measured runs packed into Parquet tables read exactly as the files they replace."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_experiment
from mgpusim.measure import run_archive
from mgpusim.measure.repeated_runs import run_spread
from mgpusim.studies.measuring import measured_folder
from mgpusim.validation.measured import read_measured

ROOT = Path(__file__).resolve().parents[1]
TRACE = ("frame,device,engine,step,task,start_ns,end_ns,bytes,waits_for\n"
         "0,gpu0,graphics,render,render0,100,900,0,\n"
         "1,gpu0,graphics,render,render0,1000,1800,0,0:render0\n")


def _runs(root: Path) -> dict[str, bytes]:
    """Two repeated-runs folders (a steady window each, runs.json beside it) and a run log."""
    files = {}
    for name, ms in (("a", [1.0, 1.1]), ("b", [2.0])):
        files[f"{name}/steady/trace.csv"] = TRACE.encode()
        files[f"{name}/steady/summary.json"] = json.dumps({"config": {}}).encode()
        files[f"{name}/runs.json"] = json.dumps({"frame_time_ms": ms}).encode()
    files["a.log"] = b"measured a\n"
    files["notes.md"] = b"not a run file\n"
    for rel, data in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    return files


def test_pack_replaces_the_run_files_and_every_reader_finds_them(tmp_path):
    files = _runs(tmp_path)
    before = {rel: run_archive.read_text(tmp_path / rel) for rel in files}
    assert run_archive.pack(tmp_path) == 7  # everything but notes.md
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.md", "run_files.parquet", "runs.parquet"]
    folder = tmp_path / "a" / "steady"
    assert run_archive.is_folder(folder) and not run_archive.is_folder(tmp_path / "c")
    assert run_archive.is_file(folder / "trace.csv") and not run_archive.is_file(folder / "frames.csv")
    assert run_archive.read_text(folder / "summary.json") == before["a/steady/summary.json"]
    with pytest.raises(FileNotFoundError):
        run_archive.read_text(folder / "machine.json")
    expected = pd.read_csv(pd.io.common.StringIO(TRACE), **run_archive.CSV_OPTIONS)
    pd.testing.assert_frame_equal(run_archive.archived_table(folder / "trace.csv"), expected)
    assert measured_folder(tmp_path, "a") == folder
    assert run_spread(folder) == (pytest.approx(0.1), 2)


def test_the_runs_in_a_folder_are_listed_alike_on_disk_and_packed(tmp_path):
    _runs(tmp_path)
    on_disk = run_archive.runs_in(tmp_path)
    assert on_disk == [tmp_path / "a" / "steady", tmp_path / "b" / "steady"]
    run_archive.pack(tmp_path)
    assert run_archive.runs_in(tmp_path) == on_disk


def test_unpack_writes_the_files_back_byte_for_byte(tmp_path):
    files = _runs(tmp_path)
    run_archive.pack(tmp_path)
    assert run_archive.unpack(tmp_path) == 7
    assert not (tmp_path / run_archive.TRACES).exists()
    assert {rel: (tmp_path / rel).read_bytes() for rel in files} == files


def test_a_trace_the_tables_cannot_hold_exactly_is_refused_and_nothing_is_deleted(tmp_path):
    _runs(tmp_path)
    empty = TRACE.replace("0:render0", "")  # waits_for all empty: read as floats, not strings
    (tmp_path / "b" / "steady" / "trace.csv").write_text(empty)
    with pytest.raises(AssertionError, match="trace.csv"):
        run_archive.pack(tmp_path)
    assert (tmp_path / "b" / "steady" / "trace.csv").read_text() == empty
    assert not (tmp_path / run_archive.TRACES).exists() and not (tmp_path / run_archive.FILES).exists()


def test_a_committed_packed_run_reads_as_it_was_measured(tmp_path):
    """The H200 study's held-out runs are committed packed; unpacked, the same run reads the same."""
    packed = ROOT / "data" / "nvidia" / "h200_x2" / "runs_si"
    assert (packed / run_archive.TRACES).is_file()
    exp = load_experiment(ROOT / "experiments" / "h200" / "sort_first.toml",
                          {"scene.width": 1920, "scene.height": 1080, "scene.passes.0.iterations": 4000})
    copy = shutil.copytree(packed, tmp_path / "runs_si")
    run_archive.unpack(copy)
    name = "sf_1080p_it4000"
    assert (copy / name / "trace.csv").is_file()
    pd.testing.assert_frame_equal(read_measured(packed / name, exp), read_measured(copy / name, exp))


def test_the_pack_script_finds_the_runs_folders_and_every_committed_run_is_packed(tmp_path):
    import importlib.util
    spec = importlib.util.spec_from_file_location("pack_runs", ROOT / "scripts" / "pack_runs.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    _runs(tmp_path / "lavapipe" / "job" / "runs")
    _runs(tmp_path / "nvidia" / "h100" / "run_single" / "x")
    assert script.runs_folders(tmp_path) == [tmp_path / "lavapipe" / "job" / "runs",
                                              tmp_path / "nvidia" / "h100" / "run_single"]
    assert script.runs_folders(ROOT / "data") == []  # nothing left to pack


def test_a_folder_s_logs_pack_into_one_table_and_come_back_byte_for_byte(tmp_path):
    logs = {"logs/measure_a.log": "group a\nrc=0\n", "logs/sweeps.log": "sweeps took 31 s\n",
            "deep/x/run.log": "é, and no newline at the end"}
    for rel, text in logs.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(text.encode("utf-8"))
    (tmp_path / "PROVENANCE.md").write_text("kept\n")
    assert run_archive.pack_logs(tmp_path) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["PROVENANCE.md", run_archive.LOGS]
    with pytest.raises(ValueError, match="no log to pack"):
        run_archive.pack_logs(tmp_path)
    assert run_archive.unpack_logs(tmp_path) == 3
    assert {rel: (tmp_path / rel).read_bytes().decode("utf-8") for rel in logs} == logs
    assert not (tmp_path / run_archive.LOGS).exists()


def test_a_folder_of_measured_tables_packs_and_calibration_reads_it_in_place(tmp_path):
    """A job's measurements folder (pass tables, their machine records, the speed probes)
    packed: calibration and the probe reader read it as from the disk (the study files' check
    of their listed tables: the offline study tests), and unpacking writes every file back
    byte for byte."""
    from mgpusim.calibration.pass_fit import read_measurements
    from mgpusim.measure.speed_probe import read_probes
    source = ROOT / "data" / "lavapipe"
    folder = tmp_path / "measurements"
    folder.mkdir()
    names = ["fragment_loop.csv", "host_copy.csv", "copy_d2h.csv"]
    for name in names:
        shutil.copy(source / name, folder / name)
        shutil.copy(source / f"{name}.machine.json", folder / f"{name}.machine.json")
    (folder / "speed.csv").write_text("point,pass,median_ms\nbefore,fragment_loop,4.5\n")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    tables = [folder / n for n in names]
    want, machine = read_measurements(tables)
    assert run_archive.pack_tables(folder) == 7
    assert sorted(p.name for p in folder.iterdir()) == [run_archive.FILES, run_archive.TRACES]
    got, got_machine = read_measurements(tables)
    pd.testing.assert_frame_equal(got, want)
    assert got_machine == machine and machine
    assert read_probes([folder / "speed.csv"])["median_ms"].tolist() == [4.5]
    assert run_archive.is_file(folder / "host_copy.csv") and run_archive.is_folder(folder)
    with pytest.raises(ValueError, match="packed already"):
        run_archive.pack_tables(folder)
    assert run_archive.unpack(folder) == 7
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_every_committed_measurements_folder_is_packed():
    import importlib.util
    spec = importlib.util.spec_from_file_location("pack_runs", ROOT / "scripts" / "pack_runs.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.table_folders(ROOT / "data") == []
