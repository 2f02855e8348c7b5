"""The campaign's output folder: `runs.parquet` (one row per run), `frames.parquet` (one row per
frame) and `PROVENANCE.md`, each written once, through a temporary file renamed into place.

Why: a campaign cut short (a failed run, a stopped session) must leave no table that looks
complete; a reader finds either the whole measurement or none of it. A folder that already holds
one is refused, so two campaigns are never mixed.
"""
from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from mgpusim.vmgpu.failures import VmgpuMeasureError

RUNS = "runs.parquet"
FRAMES = "frames.parquet"
PROVENANCE = "PROVENANCE.md"
FILES = (RUNS, FRAMES, PROVENANCE)


def check_out_folder(out: Path) -> None:
    """Refuse an output folder that already holds a measurement (or is a file)."""
    if out.exists() and not out.is_dir():
        raise VmgpuMeasureError(f"--out {out} is a file, not a folder")
    present = [f for f in FILES if (out / f).exists()]
    if present:
        raise VmgpuMeasureError(f"--out {out} already holds a measurement ({', '.join(present)}); "
                                f"give a new folder or remove those files")


def write_atomic(path: Path, data: bytes) -> None:
    """`data` to `path` through `path`'s temporary sibling, renamed into place."""
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("wb") as out:
        out.write(data)
        out.flush()
        os.fsync(out.fileno())
    tmp.replace(path)


def parquet_bytes(table: pd.DataFrame) -> bytes:
    """The table as Parquet bytes (no index column)."""
    import io  # noqa: PLC0415

    buffer = io.BytesIO()
    table.to_parquet(buffer, index=False)
    return buffer.getvalue()


def write_all(out: Path, runs: pd.DataFrame, frames: pd.DataFrame, provenance: str) -> None:
    """The two tables, then the provenance (last: a folder with PROVENANCE.md is complete)."""
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / FRAMES, parquet_bytes(frames))
    write_atomic(out / RUNS, parquet_bytes(runs))
    write_atomic(out / PROVENANCE, provenance.encode())
