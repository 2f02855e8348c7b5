"""A sweep's folder: one file per finished point, then the table, plot and description.

Why one small file per point: a point is saved whole or not at all (written to a temporary
name, flushed to disk, renamed over its final name; the folder is flushed too), so a sweep
killed with SIGKILL at any instant leaves only complete points and, at worst, a stray
temporary file that the next run removes. The table (`sweep.parquet`), plot (`sweep.png`) and
description (`sweep.json`) are replaced the same way, so a reader never sees half of one.

Layout::

    DIR/points/<id>.json   {"keys": {...}, "summary": {...}, "error": null, "wall_s": 0.03}
    DIR/sweep.parquet      one row per point of the current grid
    DIR/sweep.png          the metric against the keys (lines, or a heatmap for two keys)
    DIR/sweep.json         experiment, grid, overrides, fidelity, points, failed
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Callable, Iterable

import pandas as pd


class PointStore:
    def __init__(self, out: Path):
        self.out = out
        self.points = out / "points"
        self.points.mkdir(parents=True, exist_ok=True)

    def load(self, wanted: Iterable[str]) -> dict[str, dict[str, Any]]:
        """The saved records of the points in `wanted` (others, from an earlier grid, stay on
        disk unused); leftover temporary files of a killed run are removed."""
        for stray in [*self.points.glob(".*.tmp"), *self.out.glob(".*.tmp")]:
            stray.unlink(missing_ok=True)
        out = {}
        for pid in wanted:
            path = self.points / f"{pid}.json"
            try:
                out[pid] = json.loads(path.read_text())
            except FileNotFoundError:
                continue
            except (ValueError, OSError):  # not written by this code: run the point again
                path.unlink(missing_ok=True)
        return out

    def save(self, pid: str, record: dict[str, Any]) -> None:
        text = json.dumps(record, sort_keys=True, default=str)
        atomic_write(self.points / f"{pid}.json", lambda tmp: tmp.write_text(text))

    def finish(self, df: pd.DataFrame, keys: list[str], metric: str, spec: dict[str, Any]) -> dict[str, Path]:
        """Write the table, the plot and the description, each atomically."""
        from mgpusim.io.plot import (  # noqa: PLC0415 - matplotlib only when a folder is written
            sweep_png)

        failed = int(df["error"].notna().sum())
        files = {"table": atomic_write(self.out / "sweep.parquet", lambda tmp: df.to_parquet(tmp, index=False))}
        files["plot"] = atomic_write(self.out / "sweep.png", lambda tmp: sweep_png(df, keys, tmp, metric))
        desc = json.dumps({**spec, "failed": failed, "metric": metric}, indent=2, sort_keys=True, default=str)
        files["description"] = atomic_write(self.out / "sweep.json", lambda tmp: tmp.write_text(desc + "\n"))
        return files


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
