"""The checked table reader: every damaged table is one InputError naming the file and what is
wrong, and no module of the package opens a table any other way."""
from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.io import table_files
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError

PACKAGE = Path(__file__).resolve().parents[1] / "mgpusim"


@pytest.fixture
def parquet(tmp_path: Path) -> Path:
    path = tmp_path / "runs.parquet"
    pd.DataFrame({"run": ["a", "b"] * 50, "start_ns": range(100)}).to_parquet(path, index=False)
    return path


def _error(call, *args, **kwargs) -> str:
    with pytest.raises(InputError) as info:
        call(*args, **kwargs)
    return str(info.value)


def test_a_truncated_parquet_table_names_the_file(parquet: Path) -> None:
    parquet.write_bytes(parquet.read_bytes()[: parquet.stat().st_size // 2])
    message = _error(table_files.read_parquet, parquet)
    assert str(parquet) in message and "cut short or damaged" in message


def test_a_zeroed_parquet_table_names_the_file(parquet: Path) -> None:
    data = parquet.read_bytes()
    parquet.write_bytes(data[:8] + bytes(len(data) - 16) + data[-8:])
    message = _error(table_files.read_parquet, parquet)
    assert str(parquet) in message and "damaged" in message


def test_a_parquet_table_without_the_columns_asked_for(parquet: Path) -> None:
    message = _error(table_files.read_parquet, parquet, ["run", "path"])
    assert "missing column(s) path" in message
    assert list(table_files.read_parquet(parquet, ["run"]).columns) == ["run", "start_ns"]


@pytest.mark.parametrize("text, expected", [
    ("", "empty"),
    ("a,b\n1,2\n3\n", "line 3 has 1 of the header's 2 fields"),
    ('a,b\n1,"2\n', "cannot read as CSV"),
    ("a,b\n\0\0,1\n", "binary"),
])
def test_csv_tables_that_cannot_be_read_whole(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "t.csv"
    path.write_text(text)
    message = _error(table_files.read_csv, path)
    assert str(path) in message and expected in message


def test_a_table_this_tool_wrote_must_end_with_its_last_line(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_text("a,b\n1,2\n3,45")  # cut inside the last number: every field is there
    assert len(table_files.read_csv(path)) == 2  # a hand-written table may end so
    assert "cut short" in _error(table_files.read_csv, path, ends_whole=True)
    path.write_text("a,b\n1,2\n3,45\n")
    assert table_files.read_csv(path, ends_whole=True)["b"].tolist() == [2, 45]


@pytest.mark.parametrize("text, expected", [
    ("{", "not valid JSON"),
    ("[" * 100_000 + "]" * 100_000, "JSON"),
    ("\udcff".encode("utf-8", "surrogatepass").decode("latin-1"), "JSON"),
])
def test_json_files_that_are_not_json(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "r.json"
    path.write_text(text, encoding="latin-1")
    message = _error(table_files.read_json, path)
    assert str(path) in message and expected in message


def test_a_folder_or_nothing_is_not_a_table(tmp_path: Path) -> None:
    assert "is a folder" in _error(table_files.read_csv, tmp_path)
    assert "not found" in _error(table_files.read_parquet, tmp_path / "none.parquet")
    assert "expected a JSON object" in _error(table_files.read_json_object, _write(tmp_path / "l.json", "[1]"))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_packed_runs_folder_with_a_damaged_table_names_it(tmp_path: Path, parquet: Path) -> None:
    root = tmp_path / "runs"
    (root / "cfg").mkdir(parents=True)
    (root / "cfg" / "trace.csv").write_text("frame,task\n0,a\n")
    (root / "cfg" / "summary.json").write_text("{}")
    run_archive.pack(root)
    files = root / run_archive.FILES
    files.write_bytes(files.read_bytes()[:40])
    message = _error(run_archive.read_json, root / "cfg" / "summary.json")
    assert str(files) in message and "cut short or damaged" in message


#: Where the package may still call a library reader: the checked reader itself, and calls on
#: text that is not a file (a value of an override, JSON this process just wrote to a string).
_ALLOWED = {"io/table_files.py", "model/toml_checks.py", "model/overrides.py"}
_DIRECT = re.compile(r"\b(pd\.read_(?:csv|parquet|json|table)|pq\.read_table|json\.loads?|tomllib\.loads?)\(")
#: A line that parses text which is no file's says so (or parses what it just dumped).
_NOT_A_FILE = ("# text, not a file", "json.loads(json.dumps(")


def test_no_module_opens_a_table_but_through_the_checked_reader() -> None:
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in _ALLOWED:
            continue
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if _DIRECT.search(line) and not any(mark in line for mark in _NOT_A_FILE):
                offenders.append(f"{rel}:{number}: {line.strip()}")
    assert offenders == []
