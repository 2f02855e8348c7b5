"""The one checked way the project opens a table: Parquet, CSV, JSON and TOML files, committed
or given, each read here so that a truncated, zeroed, empty or mistyped file is one InputError
naming the file and what is wrong with it, never a pyarrow, pandas or json traceback.

Why one module: the readers were written one by one beside their callers, and every reader
that was missed (a packed runs folder's tables, a speed record) let a library error reach the
user. A test checks that no module of the package opens a table any other way.

Text that is not on disk (a file kept in a packed runs folder) is parsed with the `parse_*`
functions, named by the path it had.
"""
from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path
from typing import Any, Iterable

import pandas as pd
import pyarrow as pa

from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_INPUT_FILE_BYTES
from mgpusim.model.toml_checks import read_input_bytes
from mgpusim.model.toml_checks import read_toml as _read_toml

#: How measured CSV tables are parsed (an empty cell is missing, "NA" is a string).
CSV_OPTIONS: dict[str, Any] = {"keep_default_na": False, "na_values": [""], "encoding": "utf-8"}
#: The largest CSV table read (a capture of 10^6 passes is about 100 MiB): beyond it lies a
#: disk image or an endless device given by mistake, refused before memory runs out.
MAX_TABLE_BYTES = 1 << 30
#: Whole-row field counts are checked on tables up to this size (a cut-short row shows as a
#: row with fewer fields, which pandas would fill with missing values without a word).
_ROW_CHECK_BYTES = 64 << 20
#: Errors the Parquet and CSV readers raise for a file that is not what it claims to be.
_LIBRARY_ERRORS = (pa.ArrowException, ValueError, TypeError, NotImplementedError, KeyError,
                   IndexError, OverflowError)


def read_parquet(path: Path, columns: Iterable[str] = ()) -> pd.DataFrame:
    """A Parquet table; with `columns`, each must be there."""
    _existing_file(path, "a Parquet table")
    try:
        table = pd.read_parquet(path)
    except PermissionError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=str(path)) from None
    except (OSError, *_LIBRARY_ERRORS) as exc:  # pyarrow reports a damaged footer as OSError
        reason = re.sub(r"^Could not open Parquet input source '.*?': ", "", _short(exc))
        raise InputError(f"not a readable Parquet table: cut short or damaged ({reason})",
                         file=str(path)) from None
    return require_columns(table, columns, str(path))


def read_csv(path: Path, columns: Iterable[str] = (), ends_whole: bool = False) -> pd.DataFrame:
    """A CSV table with a header row (UTF-8); with `columns`, each must be there; `ends_whole`:
    see :func:`parse_csv`."""
    _existing_file(path, "a CSV table")
    raw = read_input_bytes(path, "a CSV table", MAX_TABLE_BYTES)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}), expected a CSV table", file=str(path)) from None
    return parse_csv(text, str(path), columns, ends_whole)


def parse_csv(text: str, file: str, columns: Iterable[str] = (), ends_whole: bool = False) -> pd.DataFrame:
    """A CSV table from its text (`file`: the path it has or had, for messages). `ends_whole`:
    the table was written by this tool, whose tables end with a newline, so one that does not
    was cut short, maybe inside its last number (which no field count would show)."""
    text = text.removeprefix("\ufeff")
    if not text.strip():
        raise InputError("the file is empty, expected a table with a header row", file=file)
    if "\0" in text:
        raise InputError("a binary file (NUL bytes), expected a CSV table", file=file)
    if ends_whole and not text.endswith("\n"):
        raise InputError("the last line does not end: the table was cut short (a table "
                         "mgpusim writes ends with a newline)", file=file)
    try:
        table = pd.read_csv(io.StringIO(text), **CSV_OPTIONS)
    except pd.errors.EmptyDataError:
        raise InputError("the file is empty, expected a table with a header row", file=file) from None
    except _LIBRARY_ERRORS as exc:  # pandas' ParserError is a ValueError
        raise InputError(f"cannot read as CSV ({_short(exc)})", file=file) from None
    if len(text) <= _ROW_CHECK_BYTES:
        _check_rows(text, len(table.columns), file)
    return require_columns(table, columns, file)


def _check_rows(text: str, width: int, file: str) -> None:
    """Every row has the header's number of fields: a shorter one is a table cut short (or a
    line edited by hand), which pandas would read as missing values."""
    for number, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        if row and len(row) < width:
            raise InputError(f"line {number} has {len(row)} of the header's {width} fields (a table "
                             f"cut short, or a line edited by hand)", file=file)


def read_json(path: Path, expected: str = "a JSON file", limit: int = MAX_INPUT_FILE_BYTES) -> Any:
    """A JSON file's value (`expected`: what the file should be, for messages; `limit`: its
    largest size in bytes, a record's by default)."""
    _existing_file(path, expected)
    raw = read_input_bytes(path, expected, limit)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}), expected {expected}", file=str(path)) from None
    return parse_json(text, str(path))


def parse_json(text: str, file: str) -> Any:
    """A JSON value from its text (`file`: the path it has or had, for messages)."""
    try:
        return json.loads(text.removeprefix("\ufeff"))
    except ValueError as exc:  # JSONDecodeError is a ValueError
        raise InputError(f"not valid JSON ({_short(exc)})", file=file) from None
    except RecursionError:
        raise InputError("not valid JSON here: nested too deeply", file=file) from None


def read_json_object(path: Path) -> dict[str, Any]:
    """A JSON file holding one object (a summary, a machine record)."""
    return json_object(read_json(path), str(path))


def json_object(data: Any, file: str) -> dict[str, Any]:
    """`data`, which must be a JSON object."""
    if not isinstance(data, dict):
        raise InputError(f"expected a JSON object, got {type(data).__name__}", file=file)
    return data


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file (:func:`mgpusim.model.toml_checks.read_toml`: the experiment and profile
    loaders' reader, here so that callers outside the model find every format in one place)."""
    return _read_toml(path)


def require_columns(table: pd.DataFrame, columns: Iterable[str], file: str) -> pd.DataFrame:
    """`table`, which must have every one of `columns`."""
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (it has "
                         f"{', '.join(map(str, table.columns)) or 'none'})", file=file)
    return table


def _existing_file(path: Path, expected: str) -> None:
    try:
        if path.is_dir():
            raise InputError(f"is a folder, expected {expected}", file=str(path))
        if not path.is_file():
            raise InputError(f"not found (or not a file), expected {expected}", file=str(path))
    except OSError as exc:  # a name too long, a loop of links
        raise InputError(f"cannot open ({exc.strerror or exc})", file=str(path)) from None


def _short(exc: BaseException) -> str:
    """A library error's first line, without the path it repeats."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."
