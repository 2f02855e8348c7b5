"""A sweep's folder: the finished points a few files at a time, then the table, plot and description.

Points are saved in batch files: those run together as lanes one file per batch, those run
one by one one file per half second of work or so (`SAVE_EVERY_S` in
:mod:`mgpusim.sweeps.grid`; until 2026-12 one JSON file per point, each flushed to disk, which
cost more than a point at the analytic level: such files are still read). A file is saved
whole or not at all (written to a temporary name, flushed to disk, renamed over its final
name; the folder is flushed too), so a sweep killed with SIGKILL at any instant leaves only
complete files and, at worst, a stray temporary file that the next run removes; what it loses
is the points finished since its last file (at most about half a second of work), which the
next run computes again. The table (`sweep.parquet`), plot (`sweep.png`) and description
(`sweep.json`) are replaced the same way, so a reader never sees half of one.

One sweep at a time writes into a folder: the store holds an exclusive lock (`flock` on
`DIR/.sweep.lock`, released by the system when the process ends, even by SIGKILL) from before
it reads the folder until the table is written. A second sweep into the same folder is refused
with one line instead of removing the first one's temporary files or interleaving its points.

Layout::

    DIR/.sweep.lock        the lock (holds the process id of the sweep that has it)
    DIR/points/batch-<hash>.parquet   points run together as lanes (analytic level): one row
                           per point, column `id` then error, wall_s and the summary's columns
    DIR/points/single-<hash>.parquet  points run one by one, saved together: the same columns
    DIR/points/<id>.json   one point run one by one, as sweeps before 2026-12 saved them (read
                           only): {"keys": {...}, "summary": {...}, "error": null, "wall_s": 0.03}
    DIR/sweep.parquet      one row per point of the current grid
    DIR/sweep.png          the metric against the keys (lines, or a heatmap for two keys)
    DIR/sweep.json         experiment, grid, overrides, fidelity, points, failed
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from types import TracebackType
from typing import Any, Callable, Iterable

import pandas as pd

from mgpusim.io import table_files
from mgpusim.model.errors import InputError

try:
    import fcntl
except ImportError:  # not a POSIX system: no lock (temporary names still differ per process)
    fcntl = None  # type: ignore[assignment]

#: The lock file in a sweep's folder.
LOCK_NAME = ".sweep.lock"


class PointStore:
    """A sweep's folder, locked while open: ``with PointStore(out) as store: ...``."""

    def __init__(self, out: Path):
        self.out = out
        self.points = out / "points"
        self.lock_fd: int | None = None

    def __enter__(self) -> "PointStore":
        self.out.mkdir(parents=True, exist_ok=True)
        self.lock_fd = _lock(self.out / LOCK_NAME)
        self.points.mkdir(exist_ok=True)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self.lock_fd is not None:
            os.close(self.lock_fd)  # releases the lock; the file stays (another may have it open)
            self.lock_fd = None

    def load(self, wanted: Iterable[str]) -> dict[str, dict[str, Any]]:
        """The saved records of the points in `wanted` (others, from an earlier grid, stay on
        disk unused); leftover temporary files of a killed run are removed (safe: the lock
        says no other sweep is writing here). A point file this code did not write (not JSON,
        or JSON of another shape) is refused, naming it: it is not deleted behind its owner."""
        for stray in [*self.points.glob(".*.tmp"), *self.out.glob(".*.tmp")]:
            stray.unlink(missing_ok=True)
        out = {}
        saved = {name[:-5] for name in os.listdir(self.points) if name.endswith(".json")}
        for pid in saved & set(wanted):
            path = self.points / f"{pid}.json"
            try:
                text = path.read_text()
            except FileNotFoundError:
                continue
            except (OSError, UnicodeDecodeError) as exc:
                raise _foreign(path, f"cannot read it ({getattr(exc, 'strerror', None) or exc})") from None
            out[pid] = check_record(text, path)
        return out

    def save(self, pid: str, record: dict[str, Any]) -> None:
        text = json.dumps(record, sort_keys=True, default=str)
        atomic_write(self.points / f"{pid}.json", lambda tmp: tmp.write_text(text))

    def save_batch(self, df: pd.DataFrame, kind: str = "batch") -> Path:
        """Points run together (a table with column `id`), or run one by one and saved
        together (`kind` "single"): one file, saved whole or not at all, named by its kind and a
        hash of its points."""
        return save_batch(self.points, df, kind)

    def load_batches(self, wanted: set[str]) -> list[pd.DataFrame]:
        """The saved batches' rows of the points in `wanted` (a batch file this code did not
        write is refused, naming it)."""
        out = []
        for path in sorted([*self.points.glob("batch-*.parquet"), *self.points.glob("single-*.parquet")]):
            try:
                df = table_files.read_parquet(path)
            except InputError as exc:
                raise _foreign(path, f"cannot read it as Parquet ({exc})") from None
            if not {"id", "error", "wall_s"} <= set(df.columns):
                raise _foreign(path, "no id, error and wall_s columns (a batch has them)")
            df = df[df["id"].isin(wanted)]
            if len(df):
                out.append(df.reset_index(drop=True))
        return out

    def finish(self, df: pd.DataFrame, keys: list[str], metric: str, spec: dict[str, Any]) -> dict[str, Path]:
        """Write the table, the plot and the description, each atomically (the plot by the
        sweep command's plotter where it has one, :mod:`mgpusim.sweeps.plotter`, while the
        table is written)."""
        from mgpusim.sweeps.plotter import draw_ahead  # noqa: PLC0415

        failed = int(df["error"].notna().sum())
        drawn = self.out / f".sweep.png.{os.getpid()}.drawn.tmp"
        plotted = df[[c for c in dict.fromkeys([*keys, metric, "error"]) if c in df]]  # what the plot reads
        plotter = draw_ahead(plotted, keys, drawn, metric)  # drawn while the table is written
        try:
            files = {"table": atomic_write(self.out / "sweep.parquet", lambda tmp: df.to_parquet(tmp, index=False))}
            if plotter is not None and plotter.drawn():
                files["plot"] = atomic_write(self.out / "sweep.png", lambda tmp: os.replace(drawn, tmp))
            else:
                from mgpusim.io.plot import sweep_png  # noqa: PLC0415 - matplotlib only when a folder is written

                files["plot"] = atomic_write(self.out / "sweep.png", lambda tmp: sweep_png(df, keys, tmp, metric))
        finally:
            if plotter is not None:
                plotter.drawn()  # (waited for before its file is removed)
            drawn.unlink(missing_ok=True)
        desc = json.dumps({**spec, "failed": failed, "metric": metric}, indent=2, sort_keys=True, default=str)
        files["description"] = atomic_write(self.out / "sweep.json", lambda tmp: tmp.write_text(desc + "\n"))
        return files


def save_batch(points: Path, df: pd.DataFrame, kind: str = "batch") -> Path:
    """:meth:`PointStore.save_batch` into a locked store's `points` folder (what the sweep's
    worker processes call: the sweep itself holds the lock)."""
    digest = hashlib.sha256("\n".join(sorted(df["id"])).encode()).hexdigest()[:20]
    return atomic_write(points / f"{kind}-{digest}.parquet", lambda tmp: df.to_parquet(tmp, index=False))


def check_record(text: str, path: Path) -> dict[str, Any]:
    """A saved point: a JSON object with `summary` (an object), `error` (text or null) and
    `wall_s` (a number), as :meth:`PointStore.save` writes it."""
    try:
        record = table_files.parse_json(text, str(path))
    except InputError:
        raise _foreign(path, "not valid JSON") from None
    if not isinstance(record, dict):
        raise _foreign(path, f"a JSON {type(record).__name__}, expected an object")
    shape = {"summary": (dict,), "error": (str, type(None)), "wall_s": (int, float)}
    for key, kinds in shape.items():
        if not isinstance(record.get(key), kinds) or isinstance(record.get(key), bool):
            raise _foreign(path, f"no {key!r} of the right type (a point record has summary, error, wall_s)")
    return record


def _foreign(path: Path, why: str) -> InputError:
    return InputError(f"{why}: not a point this sweep saved; delete it to run the point again",
                      file=str(path))


def _lock(path: Path) -> int | None:
    """An exclusive lock on `path` (created if absent), held by the returned descriptor; a
    lock another process holds is one InputError naming it."""
    if fcntl is None:
        return None
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
        os.close(fd)
        raise InputError(f"another sweep (process {holder}) is writing into this folder: wait for "
                         "it to finish, or give another --out", field=f"--out {path.parent}") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def atomic_write(path: Path, write: Callable[[Path], Any]) -> Path:
    """`write(tmp)` then rename over `path`, with the data and the rename flushed to disk."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    return path
