"""Measured runs kept compactly: a folder of runs as two Parquet tables.

A folder of committed runs (a study's calibration or held-out runs, a main job's runs) holds
hundreds of small files: per run its trace, summary, machine record, frames, and logs beside
them. :func:`pack` turns such a folder into `runs.parquet` (every run's trace rows, the run's
folder in column `run`) and `run_files.parquet` (every other file of the runs, by path, as
text); :func:`pack_tables` packs a folder of measured tables the same way (no traces).
Readers keep asking for a file by the path it had (`runs/sf_2gpu/steady/trace.csv`):
:func:`is_file`, :func:`read_text` and :func:`read_table` answer from the disk where the file is
there, else from the archive of the nearest packed folder above it. :func:`unpack` writes the
files back, byte for byte.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable, cast

import pandas as pd

from mgpusim.io import table_files as checked
from mgpusim.model.errors import InputError

#: The archive's two tables, in the packed folder.
TRACES = "runs.parquet"
FILES = "run_files.parquet"
#: A folder's measuring logs (`*.log` below it), packed as one table (path, text): they are read
#: by people, never by the tool, so no reader looks into it (:func:`unpack_logs` writes them back).
LOGS = "logs.parquet"
#: The one file of a run stored as columns (the trace schema); the rest are kept as text.
TRACE_NAME = "trace.csv"
#: How measured CSV tables are parsed (an empty cell is missing, "NA" is a string).
CSV_OPTIONS: dict[str, Any] = checked.CSV_OPTIONS


@dataclass(frozen=True)
class Archive:
    """A packed folder: its runs' traces and the text of their other files."""

    root: Path
    traces: dict[str, pd.DataFrame]  # run folder (relative, posix) -> its trace
    files: dict[str, str]  # file path (relative, posix) -> its text

    def has_folder(self, rel: str) -> bool:
        prefix = f"{rel}/" if rel else ""
        return rel in self.traces or any(p.startswith(prefix) for p in (*self.files, *self.traces))


def _rel(path: Path, root: Path) -> str:
    rel = path.relative_to(root).as_posix()
    return "" if rel == "." else rel


@lru_cache(maxsize=16)
def _load(root: Path, stamp: tuple[int, int]) -> Archive:
    """The archive of `root` (cached while its tables are unchanged: `stamp` is their mtimes);
    a table cut short, damaged or of another layout is one InputError naming it."""
    table = checked.read_parquet(root / TRACES, ["run"])
    traces = {cast(str, run): rows.drop(columns="run").reset_index(drop=True)  # the run column: names
              for run, rows in table.groupby("run", sort=False)}
    files = checked.read_parquet(root / FILES, ["path", "text"])
    return Archive(root, traces, dict(zip(files["path"], files["text"])))


def _open(root: Path) -> Archive:
    """The archive packed in `root`, read once while its two tables stay unchanged."""
    return _load(root, ((root / TRACES).stat().st_mtime_ns, (root / FILES).stat().st_mtime_ns))


def archive_of(path: Path) -> tuple[Archive, str] | None:
    """The archive holding `path` (a file or folder that is not on disk) and its relative path
    there, or None where no folder above it was packed."""
    for folder in path.parents:
        if (folder / TRACES).is_file() and (folder / FILES).is_file():
            return _open(folder), _rel(path, folder)
    return None


def runs_in(root: Path) -> list[Path]:
    """The run folders under `root`: those packed in `root`'s own archive where it has one,
    else those on disk (:func:`run_folders`)."""
    if (root / TRACES).is_file() and (root / FILES).is_file():
        return [root / rel if rel else root for rel in sorted(_open(root).traces)]
    return run_folders(root)


def is_folder(path: Path) -> bool:
    """A folder on disk, or one that a packed archive holds."""
    if path.is_dir():
        return True
    found = archive_of(path)
    return found is not None and found[0].has_folder(found[1])


def is_file(path: Path) -> bool:
    """A file on disk, or one that a packed archive holds."""
    if path.is_file():
        return True
    found = archive_of(path)
    if found is None:
        return False
    archive, rel = found
    if path.name == TRACE_NAME:
        return _rel(path.parent, archive.root) in archive.traces
    return rel in archive.files


def read_text(path: Path) -> str:
    """A text file's content, from the disk or its archive (FileNotFoundError if neither)."""
    if path.is_file():
        return path.read_bytes().decode("utf-8")
    found = archive_of(path)
    if found is None or found[1] not in found[0].files:
        raise FileNotFoundError(2, "No such file or directory", str(path))
    return found[0].files[found[1]]


def archived_table(path: Path) -> pd.DataFrame | None:
    """A CSV table that is not on disk, from its archive (None if no archive holds it): a
    trace from the traces table, any other table parsed from its text as from the file."""
    found = archive_of(path)
    if found is None:
        return None
    archive, rel = found
    if path.name == TRACE_NAME:
        trace = archive.traces.get(_rel(path.parent, archive.root))
        return None if trace is None else trace.copy()
    text = archive.files.get(rel)
    return None if text is None else checked.parse_csv(text, str(path))


def read_table(path: Path, columns: Iterable[str] = (), ends_whole: bool = False) -> pd.DataFrame:
    """A CSV or Parquet table (by extension) from the disk, else from its archive; missing,
    unreadable, empty or corrupt tables are one InputError naming the file. `ends_whole`: a
    table this tool wrote, refused where it does not end with a newline (cut short)."""
    if path.is_file():
        if path.suffix in (".parquet", ".pq"):
            return checked.read_parquet(path, columns)
        return checked.read_csv(path, columns, ends_whole)
    archived = archived_table(path)
    if archived is None:
        raise InputError("not found (or not a file)", file=str(path))
    return checked.require_columns(archived, columns, str(path))


def read_json(path: Path) -> Any:
    """A JSON file's value from the disk, else from its archive; one InputError naming the
    file where it is missing or not JSON."""
    if path.is_file():
        return checked.read_json(path)
    try:
        text = read_text(path)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=str(path)) from None
    return checked.parse_json(text, str(path))


# ----- packing -----------------------------------------------------------------------------------
def run_folders(root: Path) -> list[Path]:
    """The folders under `root` (itself included) that hold a run's trace."""
    return sorted(p.parent for p in root.rglob(TRACE_NAME))


def packed_files(root: Path) -> list[Path]:
    """What :func:`pack` takes into the archive: every file of a run folder, the repeated-runs
    records (`runs.json`) beside them, and the run logs directly in `root` (named as a run)."""
    runs = set(run_folders(root))
    names = {run.name for run in runs} | {run.parent.name for run in runs}
    chosen = {f for run in runs for f in run.iterdir() if f.is_file()}
    chosen |= set(root.rglob("runs.json")) | {f for f in root.glob("*.log") if f.stem in names}
    return sorted(chosen)


def pack(root: Path) -> int:
    """Archive `root`'s runs (:func:`packed_files`) into its two tables, check that every file
    reads back exactly as from the disk, then delete the files (and emptied folders); returns
    how many files went in. A mismatch deletes nothing: the tables are removed again and the
    error says which file."""
    files = packed_files(root)
    if not files:
        raise ValueError(f"{root}: no run to pack")
    traces, texts = [], []
    for f in files:
        rel = _rel(f, root)
        if f.name == TRACE_NAME:
            trace = checked.read_csv(f)
            traces.append(trace.assign(run=_rel(f.parent, root))[["run", *trace.columns]])
        else:
            texts.append((rel, f.read_bytes().decode("utf-8")))
    return _write_checked(root, pd.concat(traces, ignore_index=True), texts, files)


def _write_checked(root: Path, traces: pd.DataFrame, texts: list[tuple[str, str]],
                   files: list[Path]) -> int:
    """Write the archive's two tables, check that every one of `files` reads back exactly as
    from the disk, then delete them; on a mismatch delete the tables instead and raise."""
    traces.to_parquet(root / TRACES, index=False, compression="zstd")
    pd.DataFrame(texts, columns=["path", "text"]).to_parquet(root / FILES, index=False,
                                                              compression="zstd")
    try:
        _check_round_trip(root, files)
    except AssertionError:
        (root / TRACES).unlink()
        (root / FILES).unlink()
        raise
    _remove(files, root)
    return len(files)


def _remove(files: list[Path], root: Path) -> None:
    """Delete packed `files`, and the folders below `root` they leave empty."""
    for f in files:
        f.unlink()
    for folder in sorted({f.parent for f in files}, key=lambda p: -len(p.parts)):
        while folder != root and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
            folder = folder.parent


def _check_round_trip(root: Path, files: list[Path]) -> None:
    archive = _open(root)
    for f in files:
        if f.name == TRACE_NAME:
            stored = archive.traces[_rel(f.parent, root)]
            pd.testing.assert_frame_equal(stored, checked.read_csv(f), obj=str(f))
        else:
            assert archive.files[_rel(f, root)] == f.read_bytes().decode("utf-8"), str(f)


def unpack(root: Path) -> int:
    """Write a packed folder's files back (traces as CSV) and remove its tables; returns how
    many files were written."""
    archive = _open(root)
    _write_texts(root, archive.files.items())
    for run, trace in archive.traces.items():
        (root / run).mkdir(parents=True, exist_ok=True)
        trace.to_csv(root / run / TRACE_NAME, index=False)
    (root / TRACES).unlink()
    (root / FILES).unlink()
    return len(archive.files) + len(archive.traces)


def table_files(root: Path) -> list[Path]:
    """What :func:`pack_tables` takes into the archive: every file below `root` but the
    archive's own tables and the measuring logs."""
    own = {root / TRACES, root / FILES, root / LOGS}
    return sorted(f for f in root.rglob("*") if f.is_file() and f not in own and f.suffix != ".log")


def pack_tables(root: Path) -> int:
    """Archive a folder of measured tables (a job's `measurements/`: pass tables, their
    `.machine.json` records, the speed probes) as :func:`pack` archives runs, every file as
    text in `run_files.parquet` beside an empty `runs.parquet`, so that the same readers
    (:func:`is_file`, :func:`read_text`, :func:`read_table`) find them; checked, then the files
    deleted. Returns how many files went in."""
    if (root / TRACES).exists() or (root / FILES).exists():
        raise ValueError(f"{root} is packed already: unpack it first")
    files = table_files(root)
    if not files:
        raise ValueError(f"{root}: no table to pack")
    texts = [(_rel(f, root), f.read_bytes().decode("utf-8")) for f in files]
    return _write_checked(root, pd.DataFrame({"run": pd.Series(dtype="string")}), texts, files)


# ----- logs --------------------------------------------------------------------------------------
def pack_logs(root: Path) -> int:
    """Pack every `*.log` file below `root` into `root/logs.parquet`, check that each reads back
    exactly, then delete them (and emptied folders); returns how many went in."""
    files = sorted(root.rglob("*.log"))
    if not files:
        raise ValueError(f"{root}: no log to pack")
    if (root / LOGS).exists():
        raise ValueError(f"{root / LOGS} exists: unpack it first")
    texts = [(_rel(f, root), f.read_bytes().decode("utf-8")) for f in files]
    pd.DataFrame(texts, columns=["path", "text"]).to_parquet(root / LOGS, index=False, compression="zstd")
    stored = checked.read_parquet(root / LOGS, ["path", "text"])
    if list(zip(stored["path"], stored["text"])) != texts:
        (root / LOGS).unlink()
        raise AssertionError(f"{root / LOGS} does not read back as the logs")
    _remove(files, root)
    return len(files)


def unpack_logs(root: Path) -> int:
    """Write `root/logs.parquet`'s logs back byte for byte and remove the table."""
    table = checked.read_parquet(root / LOGS, ["path", "text"])
    _write_texts(root, zip(table["path"], table["text"]))
    (root / LOGS).unlink()
    return len(table)


def _write_texts(root: Path, files: Iterable[tuple[str, str]]) -> None:
    """Write each (relative path, text) below `root` byte for byte, making its folders."""
    for rel, text in files:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(text.encode("utf-8"))
