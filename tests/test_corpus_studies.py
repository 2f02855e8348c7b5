"""A held-out style corpus over the study commands: runs folders and tables as a user ends up
with them (cut short, zeroed, another study's, edited by hand, a set given twice), each run
through `mgpusim study validate | calibrate | floor | measure` and classified
(tests/corpus_harness.py). Every case must end in a clean error naming the file or option, or
in a correct result: no traceback, no hang, no silent wrong result.

The runs are a two-by-two subset of the committed two-H100 study (its own experiments and
runs), so that a case costs about a second."""
from __future__ import annotations

import json
import os
import shutil
import tomllib
from pathlib import Path
from typing import Callable

import pandas as pd
import pytest
import tomli_w

from mgpusim.measure import run_archive
from tests.corpus_harness import CLEAN_ERROR, CORRECT, Case, names, run_case

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h100_x2" / "study.toml"
RUNS = ROOT / "data" / "nvidia" / "h100_x2" / "runs"
OTHER = {"h100x4": ROOT / "data" / "nvidia" / "h100_x4" / "runs",
         "h200x2": ROOT / "data" / "nvidia" / "h200_x2" / "runs_2026-11-27"}
CALIBRATION = ("afr_1gpu_1440p_it2000", "afr_2gpu_4k_it1000")
HELD_OUT = ("afr_2gpu_1080p_it4000", "afr_2gpu_1440p_it2000")
FIRST = CALIBRATION[0]
TABLES_STUDY = ROOT / "experiments" / "h100" / "study.toml"


@pytest.fixture(scope="module")
def unpacked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The subset's runs, unpacked once (cases copy them)."""
    root = tmp_path_factory.mktemp("corpus") / "packed"
    shutil.copytree(RUNS, root)
    run_archive.unpack(root)
    subset = root.parent / "runs"
    subset.mkdir()
    for name in (*CALIBRATION, *HELD_OUT):
        shutil.move(root / name, subset / name)
    return subset


_SOURCE: dict[str, Path] = {}


def _study_file(tmp: Path) -> Path:
    """The subset study in `tmp` (its paths relative, as a study's must be), both halves
    reading the subset's runs (read only: a case's damaged copy is given with --runs)."""
    data = tomllib.loads(STUDY.read_text())
    base = STUDY.parent
    data["profile"] = _rel(base / data["profile"], tmp)
    data["microbenchmarks"]["tables"] = _rel(base / data["microbenchmarks"]["tables"], tmp)
    data["calibration"]["runs"] = data["held_out"]["runs"] = _rel(_SOURCE["runs"], tmp)
    data["calibration"]["host_grid"] = {"dispatch_ns": [0, 400000]}
    for half, kept in (("calibration", CALIBRATION), ("held_out", HELD_OUT)):
        configs = [c for c in data[half]["config"] if c["name"] in kept]
        for c in configs:
            c["experiment"] = _rel(base / c["experiment"], tmp)
        data[half]["config"] = configs
    path = tmp / "study.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def _rel(path: Path, tmp: Path) -> str:
    """`path` relative to the study file's folder `tmp` (a study's paths must be relative)."""
    return os.path.relpath(path.resolve(), tmp.resolve())


def _runs(tmp: Path) -> Path:
    runs = tmp / "runs"
    if not runs.exists():
        shutil.copytree(_SOURCE["runs"], runs)
    return runs


def _steady(tmp: Path, name: str = FIRST) -> Path:
    return _runs(tmp) / name / "steady"


# ----- damages to a runs folder: each returns the --runs folder to give --------------------------
Damage = Callable[[Path], Path]


def _packed(edit: Callable[[Path], None]) -> Damage:
    """The runs packed (as committed), then one of the archive's tables edited."""
    def make(tmp: Path) -> Path:
        runs = _runs(tmp)
        run_archive.pack(runs)
        edit(runs)
        return runs
    return make


def _cut(name: str, keep: float | int) -> Callable[[Path], None]:
    def edit(runs: Path) -> None:
        data = (runs / name).read_bytes()
        (runs / name).write_bytes(data[: int(len(data) * keep) if isinstance(keep, float) else keep])
    return edit


def _zero_middle(name: str) -> Callable[[Path], None]:
    def edit(runs: Path) -> None:
        data = (runs / name).read_bytes()
        (runs / name).write_bytes(data[:8] + bytes(len(data) - 16) + data[-8:])
    return edit


def _replace(name: str, content: bytes) -> Callable[[Path], None]:
    def edit(runs: Path) -> None:
        (runs / name).write_bytes(content)
    return edit


def _other_parquet(name: str, columns: dict[str, list]) -> Callable[[Path], None]:
    def edit(runs: Path) -> None:
        pd.DataFrame(columns).to_parquet(runs / name, index=False)
    return edit


def _in_run(file: str, edit: Callable[[Path], None], name: str = FIRST) -> Damage:
    """One file of a run, edited on disk."""
    def make(tmp: Path) -> Path:
        folder = _steady(tmp, name)
        edit(folder / file)
        return _runs(tmp)
    return make


def _text(content: str) -> Callable[[Path], None]:
    return lambda path: path.write_text(content)


def _json_edit(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def edit(path: Path) -> None:
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data))
    return edit


def _csv_edit(change: Callable[[str], str]) -> Callable[[Path], None]:
    return lambda path: path.write_text(change(path.read_text()))


def _set_key(*keys_value: object) -> Callable[[dict], None]:
    *keys, value = keys_value

    def change(data: dict) -> None:
        node = data
        for k in keys[:-1]:
            node = node[k]  # type: ignore[index]
        node[keys[-1]] = value  # type: ignore[index]
    return change


def _all_machines(device: str) -> Damage:
    def make(tmp: Path) -> Path:
        for machine in (_runs(tmp) / FIRST).rglob("machine.json"):
            _json_edit(lambda d: d["gpus"][0].__setitem__("device", device))(machine)
        return _runs(tmp)
    return make


def _remove(*names_: str) -> Damage:
    def make(tmp: Path) -> Path:
        for name in names_:
            shutil.rmtree(_runs(tmp) / name)
        return _runs(tmp)
    return make


def _rename(old: str, new: str) -> Damage:
    def make(tmp: Path) -> Path:
        (_runs(tmp) / old).rename(_runs(tmp) / new)
        return _runs(tmp)
    return make


def _record(study: str) -> Damage:
    def make(tmp: Path) -> Path:
        (_runs(tmp) / "study.json").write_text(json.dumps({"study": study}))
        return _runs(tmp)
    return make


def _empty(tmp: Path) -> Path:
    (tmp / "empty").mkdir()
    return tmp / "empty"


def _a_file(tmp: Path) -> Path:
    (tmp / "runs.txt").write_text("runs")
    return tmp / "runs.txt"


def _link_loop(tmp: Path) -> Path:
    runs = _runs(tmp)
    os.symlink(runs / "loop", runs / "loop")
    return runs


DAMAGES: dict[str, tuple[Damage, tuple[str, ...]]] = {
    "packed-runs-cut-half": (_packed(_cut(run_archive.TRACES, 0.5)), (run_archive.TRACES,)),
    "packed-runs-cut-10-bytes": (_packed(_cut(run_archive.TRACES, 10)), (run_archive.TRACES,)),
    "packed-runs-empty-file": (_packed(_cut(run_archive.TRACES, 0)), (run_archive.TRACES,)),
    "packed-files-zeroed": (_packed(_zero_middle(run_archive.FILES)), (run_archive.FILES,)),
    "packed-files-cut": (_packed(_cut(run_archive.FILES, 0.7)), (run_archive.FILES,)),
    "packed-runs-is-csv": (_packed(_replace(run_archive.TRACES, b"run,frame\nx,0\n")), (run_archive.TRACES,)),
    "packed-runs-random": (_packed(_replace(run_archive.TRACES, os.urandom(4096))), (run_archive.TRACES,)),
    "packed-runs-other-table": (_packed(_other_parquet(run_archive.TRACES, {"x": [1]})), (run_archive.TRACES,)),
    "packed-files-no-text": (_packed(_other_parquet(run_archive.FILES, {"path": ["a"]})), (run_archive.FILES,)),
    "empty-folder": (_empty, ("empty",)),
    "a-file": (_a_file, ("runs.txt",)),
    "no-such-folder": (lambda tmp: tmp / "nowhere", ("nowhere",)),
    "another-study-h100x4": (lambda tmp: OTHER["h100x4"], ("another study",)),
    "another-study-h200x2": (lambda tmp: OTHER["h200x2"], ("another study",)),
    "one-calibration-run-missing": (_remove(FIRST), (FIRST,)),
    "every-calibration-run-missing": (_remove(*CALIBRATION), (FIRST,)),
    "a-run-renamed": (_rename(FIRST, "afr_1gpu_renamed"), (FIRST,)),
    "recorded-for-another-study": (_record("lavapipe"), ("lavapipe",)),
    "another-card": (_all_machines("NVIDIA H200"), ("NVIDIA H200",)),
    "another-card-lavapipe": (_all_machines("llvmpipe (LLVM 15.0.6, 256 bits)"), ("llvmpipe",)),
    "another-experiment": (_in_run("summary.json", _json_edit(_set_key("config", "experiment", "h200_afr"))),
                           ("summary.json",)),
    "another-resolution": (_in_run("summary.json", _json_edit(_set_key("config", "width", 1280))),
                           ("summary.json",)),
    "another-gpu-count": (_in_run("summary.json", _json_edit(_set_key("config", "gpus", 4))), ("summary.json",)),
    "summary-not-json": (_in_run("summary.json", _text("{config")), ("summary.json",)),
    "summary-a-list": (_in_run("summary.json", _text("[1, 2]")), ("summary.json",)),
    "summary-nested-deep": (_in_run("summary.json", _text("[" * 50_000 + "]" * 50_000)), ("summary.json",)),
    "summary-empty": (_in_run("summary.json", _text("")), ("summary.json",)),
    "summary-config-a-string": (_in_run("summary.json", _text('{"config": "x"}')), ("summary.json",)),
    "summary-removed": (_in_run("summary.json", lambda p: p.unlink()), ("summary.json",)),
    "machine-not-json": (_in_run("machine.json", _text("nope")), ("machine.json",)),
    "machine-binary": (_in_run("machine.json", lambda p: p.write_bytes(b"\xff\xfe\0\0")), ("machine.json",)),
    "trace-cut-mid-line": (_in_run("trace.csv", _csv_edit(lambda t: t[:-7])), ("trace.csv",)),
    "trace-cut-mid-row": (_in_run("trace.csv", _csv_edit(lambda t: t[: t.rindex("\n", 0, len(t) - 1)] + "\n0,gpu")),
                          ("trace.csv",)),
    "trace-header-only": (_in_run("trace.csv", _csv_edit(lambda t: t.splitlines()[0] + "\n")), ("trace.csv",)),
    "trace-empty": (_in_run("trace.csv", _text("")), ("trace.csv",)),
    "trace-binary": (_in_run("trace.csv", lambda p: p.write_bytes(b"\0" * 64)), ("trace.csv",)),
    "trace-not-utf8": (_in_run("trace.csv", lambda p: p.write_bytes(p.read_bytes() + b"\xff\n")), ("trace.csv",)),
    "trace-column-renamed": (_in_run("trace.csv", _csv_edit(lambda t: t.replace("start_ns", "start_us", 1))),
                             ("trace.csv",)),
    "trace-negative-time": (_in_run("trace.csv", _csv_edit(lambda t: t.replace(",", ",-", 1))), ("trace.csv",)),
    "trace-text-in-time": (_in_run("trace.csv", _csv_edit(lambda t: _cell(t, "end_ns", "soon"))), ("trace.csv",)),
    "trace-removed": (_in_run("trace.csv", lambda p: p.unlink()), (FIRST, "trace")),
    "runs-json-broken": (lambda tmp: (_text("{")(_runs(tmp) / FIRST / "runs.json"), _runs(tmp))[1], ("runs.json",)),
    "runs-json-no-times": (lambda tmp: (_text('{"frame_time_ms": "x"}')(_runs(tmp) / FIRST / "runs.json"),
                                        _runs(tmp))[1], ("runs.json",)),
}


def _cell(text: str, column: str, value: str) -> str:
    """`text` (a CSV table) with `column` of its first row set to `value`."""
    lines = text.splitlines()
    header = lines[0].split(",")
    row = lines[1].split(",")
    row[header.index(column)] = value
    return "\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n"


def _study_argv(step: str, damage: Damage, *extra: str) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        runs = damage(tmp)
        study = _study_file(tmp)
        return ["study", step, str(study), "--runs", str(runs), "--out", str(tmp / "out"), *extra]
    return make


def _errors_json_has(rows: int) -> Callable[[Path, str], bool]:
    """The validation compared `rows` configurations in all, every one it was given, and its
    replay is as close as the committed study's (within 5 %: the replay of these runs)."""
    def check(tmp: Path, _text_out: str) -> bool:
        stats = json.loads((tmp / "out" / "errors.json").read_text())
        halves = [v for v in stats.values() if isinstance(v, dict) and "configurations" in v]
        return (sum(h["configurations"] for h in halves) == rows
                and all(h["replay_worst_abs_frame_time_error"] < 0.05 for h in halves)
                and not any("without_runs" in h for h in halves))
    return check


def _report_says_missing(name: str) -> Callable[[Path, str], bool]:
    def check(tmp: Path, _text_out: str) -> bool:
        head = (tmp / "out" / "report.md").read_text().split("\n\n")[:3]
        return any("Not every configuration" in part and name in part for part in head)
    return check


def _profile_written(tmp: Path, _text_out: str) -> bool:
    return "dispatch_ns" in (tmp / "out" / "profile.toml").read_text()


def study_cases() -> list[Case]:
    cases = []
    for name, (damage, needles) in DAMAGES.items():
        cases.append(Case(f"validate-{name}", _study_argv("validate", damage, "--no-figures"), needles))
    for name in ("packed-runs-cut-half", "packed-files-zeroed", "packed-runs-other-table", "empty-folder",
                 "a-file", "another-study-h100x4", "another-study-h200x2", "one-calibration-run-missing",
                 "recorded-for-another-study", "another-card", "another-experiment", "summary-not-json",
                 "trace-cut-mid-line", "trace-column-renamed", "trace-negative-time", "trace-cut-mid-row"):
        damage, needles = DAMAGES[name]
        cases.append(Case(f"calibrate-{name}", _study_argv("calibrate", damage), needles))
    cases += [
        Case("validate-held-out-missing", _study_argv("validate", _remove(HELD_OUT[0]), "--no-figures", "--held-out"),
             (HELD_OUT[0],)),
        Case("validate-held-out-all-missing", _study_argv("validate", _remove(*HELD_OUT), "--no-figures",
                                                           "--held-out"), (HELD_OUT[0],)),
        Case("validate-clean", _study_argv("validate", lambda tmp: _runs(tmp), "--no-figures"),
             check=_errors_json_has(2)),
        Case("validate-clean-held-out", _study_argv("validate", lambda tmp: _runs(tmp), "--no-figures", "--held-out"),
             check=_errors_json_has(4)),
        Case("validate-allow-missing", _study_argv("validate", _remove(CALIBRATION[1]), "--no-figures",
                                                   "--allow-missing"), check=_report_says_missing(CALIBRATION[1])),
        Case("validate-allow-missing-still-not-another-study", _study_argv(
            "validate", lambda tmp: OTHER["h100x4"], "--no-figures", "--allow-missing"), ("another study",)),
        Case("validate-a-link-loop-beside-the-runs", _study_argv("validate", _link_loop, "--no-figures"),
             check=_errors_json_has(2)),
        Case("calibrate-a-broken-record-it-does-not-read", _study_argv(
            "calibrate", lambda tmp: (_text("{")(_runs(tmp) / FIRST / "runs.json"), _runs(tmp))[1]),
             check=_profile_written),
        Case("validate-packed-clean", _study_argv("validate", _packed(lambda runs: None), "--no-figures"),
             check=_errors_json_has(2)),
        Case("calibrate-clean", _study_argv("calibrate", lambda tmp: _runs(tmp)), check=_profile_written),
        Case("calibrate-allow-missing", _study_argv("calibrate", _remove(CALIBRATION[1]), "--allow-missing"),
             check=_profile_written),
    ]
    return cases + table_cases() + floor_cases() + measure_cases()


# ----- the measure tables a calibration reads ---------------------------------------------------
def _tables_study(tmp: Path, edit: Callable[[Path], None]) -> list[str]:
    """The one-H100 study (tables only) with its tables copied into `tmp`, one edited."""
    tables = tmp / "tables"
    shutil.copytree(ROOT / "data" / "nvidia" / "h100_x1", tables)
    edit(tables)
    data = tomllib.loads(TABLES_STUDY.read_text())
    data["profile"] = _rel(TABLES_STUDY.parent / data["profile"], tmp)
    data["microbenchmarks"]["tables"] = _rel(tables, tmp)
    copy_from = data["calibration"]["copy_from"]
    copy_from["profile"] = _rel(TABLES_STUDY.parent / copy_from["profile"], tmp)
    (tmp / "study.toml").write_text(tomli_w.dumps(data))
    return ["study", "calibrate", str(tmp / "study.toml"), "--out", str(tmp / "out")]


def _table(name: str, change: Callable[[str], str] | Callable[[bytes], bytes], binary: bool = False):
    def edit(tables: Path) -> None:
        path = tables / name
        if binary:
            path.write_bytes(change(path.read_bytes()))  # type: ignore[arg-type]
        else:
            path.write_text(change(path.read_text()))  # type: ignore[arg-type]
    return lambda tmp: _tables_study(tmp, edit)


def _rename_column(old: str, new: str) -> Callable[[str], str]:
    def change(text: str) -> str:
        header, rest = text.split("\n", 1)
        return ",".join(new if c == old else c for c in header.split(",")) + "\n" + rest
    return change


def _same_profile(tmp: Path, _text_out: str) -> bool:
    """The calibration read the edited table as the original: the same coefficients."""
    clean = tmp / "clean"
    clean.mkdir()
    args = _tables_study(clean, lambda tables: None)
    from mgpusim.cli import main
    assert main(args) == 0
    strip = lambda t: [line for line in t.splitlines()  # noqa: E731 - the fit report and command differ
                       if not line.startswith("#") and "fitted by `mgpusim" not in line]
    return strip((tmp / "out" / "profile.toml").read_text()) == strip((clean / "out" / "profile.toml").read_text())


def table_cases() -> list[Case]:
    frag, mesh = "fragment_loop.csv", "mesh.csv"
    cases = [Case(f"table-{frag}-{col}-renamed", _table(frag, _rename_column(col, col + "_x")), (frag,))
             for col in ("device", "gpu", "gpus", "pass", "width", "height", "iterations", "repetition",
                         "duration_ns", "bytes")]
    cases += [Case(f"table-{mesh}-{col}-renamed", _table(mesh, _rename_column(col, col.upper())), (mesh,))
              for col in ("triangles", "width", "duration_ns", "bytes")]
    lines = lambda t: t.splitlines(keepends=True)  # noqa: E731
    cases += [
        Case("table-cut-mid-number", _table(frag, lambda t: t[:-4]), (frag,)),
        Case("table-cut-mid-row", _table(frag, lambda t: "".join(lines(t)[:-1]) + lines(t)[-1][:12] + "\n"), (frag,)),
        Case("table-header-only", _table(frag, lambda t: lines(t)[0]), (frag,)),
        Case("table-empty", _table(frag, lambda t: ""), (frag,)),
        Case("table-binary", _table(frag, lambda b: b"\0\1\2" * 30, binary=True), (frag,)),
        Case("table-latin1", _table(frag, lambda b: b + "caf\xe9,1\n".encode("latin-1"), binary=True), (frag,)),
        Case("table-extra-field", _table(frag, lambda t: t.replace("\n", ",9\n", 2)), (frag,)),
        Case("table-extra-column", _table(frag, lambda t: t.replace("\n", ",note\n", 1).replace("\n", ",x\n")), (frag,)),
        Case("table-negative-duration", _table(frag, lambda t: _cell(t, "duration_ns", "-5")), (frag,)),
        Case("table-nan-duration", _table(frag, lambda t: _cell(t, "duration_ns", "nan")), (frag,)),
        Case("table-inf-width", _table(frag, lambda t: _cell(t, "width", "inf")), (frag,)),
        Case("table-text-iterations", _table(frag, lambda t: _cell(t, "iterations", "many")), (frag,)),
        Case("table-unknown-pass", _table(frag, lambda t: _cell(t, "pass", "fragment_lop")), (frag,)),
        Case("table-missing-iterations", _table(frag, lambda t: _cell(t, "iterations", "")), (frag,)),
        Case("table-removed", lambda tmp: _tables_study(tmp, lambda tables: (tables / frag).unlink()), (frag,)),
        Case("table-a-folder", lambda tmp: _tables_study(tmp, lambda tables: ((tables / frag).unlink(),
                                                                               (tables / frag).mkdir())), (frag,)),
        Case("table-machine-record-broken", _table("copy_d2h.csv.machine.json", lambda t: "{"),
             ("copy_d2h.csv.machine.json",)),
        Case("table-bom", _table(frag, lambda t: "\ufeff" + t), check=_same_profile),
        Case("table-crlf", _table(frag, lambda t: t.replace("\n", "\r\n")), check=_same_profile),
        Case("table-rows-shuffled", _table(frag, lambda t: lines(t)[0] + "".join(sorted(lines(t)[1:]))),
             check=_same_profile),
    ]
    return cases


# ----- study floor ---------------------------------------------------------------------------------
def _floor_argv(*sets: Callable[[Path], Path], profile: bool = True) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        study = _study_file(tmp)
        argv = ["study", "floor", str(study), "--out", str(tmp / "out")]
        for s in sets:
            argv += ["--runs", str(s(tmp))]
        if profile:
            argv += ["--profile", str(ROOT / "hardware_profiles" / "h100_x2.toml")]
        return argv
    return make


def _copy_of_runs(tmp: Path) -> Path:
    shutil.copytree(_runs(tmp), tmp / "copy")
    return tmp / "copy"


def _second_set(tmp: Path) -> Path:
    """Another set of the same configurations: the second repeat as the compared run."""
    other = tmp / "set2"
    shutil.copytree(_runs(tmp), other)
    for name in (*CALIBRATION, *HELD_OUT):
        shutil.rmtree(other / name / "steady")
        (other / name / "runs.json").unlink()
        shutil.rmtree(other / name / "run0")
        (other / name / "run1").rename(other / name / "run0")
    return other


def _floor_done(tmp: Path, _text_out: str) -> bool:
    table = pd.read_csv(tmp / "out" / "replay_floor.csv")
    return len(table) == 4 and (table["half_range"] >= 0).all()


def floor_cases() -> list[Case]:
    runs = lambda tmp: _runs(tmp)  # noqa: E731
    return [
        Case("floor-one-set", _floor_argv(runs), ("--runs",)),
        Case("floor-same-set-twice", _floor_argv(runs, runs), ("same runs",)),
        Case("floor-a-copy", _floor_argv(runs, _copy_of_runs), ("same runs",)),
        Case("floor-another-study", _floor_argv(runs, lambda tmp: OTHER["h100x4"]), ("another study",)),
        Case("floor-an-empty-set", _floor_argv(runs, _empty), ("empty",)),
        Case("floor-a-file", _floor_argv(runs, _a_file), ("runs.txt",)),
        Case("floor-no-profile", _floor_argv(runs, _second_set, profile=False), ("profile.toml",)),
        Case("floor-damaged-set", _floor_argv(runs, _packed(_cut(run_archive.TRACES, 0.5))), (run_archive.TRACES,)),
        Case("floor-two-sets", _floor_argv(runs, _second_set), check=_floor_done),
    ]


# ----- study measure: refused before any device is touched -------------------------------------------
def _measure_argv(*extra: str, edit: Callable[[dict], None] | None = None) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        study = _study_file(tmp)
        if edit is not None:
            data = tomllib.loads(study.read_text())
            edit(data)
            study.write_text(tomli_w.dumps(data))
        return ["study", "measure", str(study), "--out", str(tmp / "out"), *extra]
    return make


def measure_cases() -> list[Case]:
    return [
        Case("measure-only-matches-nothing", _measure_argv("--only", "^zzz"), ("--only",)),
        Case("measure-only-bad-regex", _measure_argv("--only", "(("), ("--only",)),
        Case("measure-devices-text", _measure_argv("--devices", "a,b"), ("--devices",)),
        Case("measure-devices-negative", _measure_argv("--devices", "-1"), ("devices",)),
        Case("measure-out-is-a-file", lambda tmp: [*_measure_argv()(tmp)[:-2], "--out", str(_a_file(tmp))],
             ("runs.txt",)),
        Case("measure-study-missing", lambda tmp: ["study", "measure", str(tmp / "none.toml")], ("none.toml",)),
        Case("measure-study-not-toml", lambda tmp: ["study", "measure", str(_a_file(tmp))], ("runs.txt",)),
        Case("measure-config-twice", _measure_argv(edit=lambda d: d["calibration"]["config"].append(
            dict(d["calibration"]["config"][0]))), (FIRST,)),
        Case("measure-unknown-key", _measure_argv(edit=lambda d: d["runs"].__setitem__("repeatz", 2)), ("repeatz",)),
        Case("measure-repeats-zero", _measure_argv(edit=lambda d: d["runs"].__setitem__("repeats", 0)), ("repeats",)),
    ]


CASES = study_cases()


@pytest.mark.parametrize("case", CASES, ids=list(names(CASES)))
def test_case(case: Case, unpacked: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _SOURCE["runs"] = unpacked
    outcome = run_case(case, tmp_path, lambda: tuple(capsys.readouterr()))  # type: ignore[arg-type,return-value]
    assert outcome.kind in (CLEAN_ERROR, CORRECT) and (outcome.kind == CORRECT) == (case.check is not None), \
        f"{outcome.kind}: {outcome.detail}"
