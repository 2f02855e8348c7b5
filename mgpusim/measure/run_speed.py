"""Each measured run's speed record (`runs/run_speed.csv`): the speed probe just before and
just after the run, what else loaded the cores meanwhile, and which run a configuration's
comparison used.

Why a row per run: the machine's speed moves within minutes, so the speed that matters for a
run's prediction is the one at that run (:mod:`mgpusim.measure.speed_norm` scales the profile
by it and flags the runs it cannot trust); a probe per round of runs is minutes away from most.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from mgpusim.measure import run_archive
from mgpusim.measure import speed_norm as sn

FILE = "run_speed.csv"
#: before_ms / after_ms: the fragment-loop probe (the one normalization uses); *_mesh_ms: the
#: mesh probe (shown, not used: lavapipe's mesh runs in two modes 1.3x apart by itself);
#: other_cores / steal_cores: mean cores other processes used / the hypervisor took during the
#: run; load_1min: the kernel's 1-minute load average after the run (what `uptime` says).
COLUMNS = ["config", "run", "before_ms", "after_ms", "before_mesh_ms", "after_mesh_ms",
           "other_cores", "steal_cores", "load_1min", "unix_time"]
NORMALIZING_PASS = "fragment_loop"


def record(config: str, run: str, before: Sequence[dict[str, Any]],
           after: Sequence[dict[str, Any]], load: dict[str, float]) -> dict[str, Any]:
    """One run's row from its probe rows before and after (speed_probe's rows) and its load."""
    def ms(rows: Sequence[dict[str, Any]], name: str) -> float:
        return next(float(r["median_ms"]) for r in rows if r["pass"] == name)
    return {"config": config, "run": run,
            "before_ms": ms(before, NORMALIZING_PASS), "after_ms": ms(after, NORMALIZING_PASS),
            "before_mesh_ms": ms(before, "mesh"), "after_mesh_ms": ms(after, "mesh"),
            "other_cores": load.get("other_cores", float("nan")),
            "steal_cores": load.get("steal_cores", float("nan")),
            "load_1min": round(os.getloadavg()[0], 2), "unix_time": round(time.time(), 1)}


def append(path: Path, row: dict[str, Any]) -> None:
    """Add `row` to the table at `path`, written whole or not at all."""
    from mgpusim.io.writers import append_rows  # noqa: PLC0415

    append_rows(path, read(path), [row], COLUMNS)


def read(path: Path) -> pd.DataFrame:
    """The table at `path` (empty, with its columns, where there is none)."""
    if not run_archive.is_file(path):
        return pd.DataFrame(columns=COLUMNS)
    return run_archive.read_table(path)


def compared_run(root: Path, name: str) -> str:
    """Which of configuration `name`'s runs under `root` its comparison used: the run its steady
    window came from (`runs.json`), else the first."""
    choice = root / name / "runs.json"
    if run_archive.is_file(choice):  # on disk, or in the folder's packed archive
        record = run_archive.read_json(choice)
        return str(record.get("run", "run0")) if isinstance(record, dict) else "run0"
    return "run0"


def report_lines(table: pd.DataFrame) -> list[str]:
    """The report's account of the per-run probes (nothing without any): how far the machine's
    speed and load moved from run to run, and the rule the normalized columns follow."""
    if table.empty:
        return []
    probe = (table["before_ms"] * table["after_ms"]) ** 0.5
    moved = table[["before_ms", "after_ms"]].max(axis=1) / table[["before_ms", "after_ms"]].min(axis=1) - 1
    return ["## The machine's speed at each run", "",
            f"The fragment-loop probe was timed just before and just after each of the "
            f"{len(table)} runs: {probe.min():.2f} / {probe.median():.2f} / {probe.max():.2f} ms "
            f"(fastest / median / slowest run), before and after one run {moved.median():.1%} "
            f"apart (median, worst {moved.max():.1%}). Other processes used "
            f"{table['other_cores'].median():.2f} cores during the median run (most "
            f"{table['other_cores'].max():.2f}); the 1-minute load average read "
            f"{table['load_1min'].min():.2f}-{table['load_1min'].max():.2f}. Each run is also "
            f"predicted at its own speed: the profile scaled by the run's probe over the median "
            f"probe of the calibration runs (`probe ratio`; passes, copies and the host's CPU "
            f"work scale, see docs/validation.md). A run is **flagged** when its probes before and "
            f"after differ by more than {sn.DISAGREEMENT_LIMIT:.0%} or other processes used "
            f"more than {sn.OTHER_CORES_LIMIT:g} cores during it: its speed is the least known. "
            f"Every run stays in the verdict, each with its band (how far its probes and repeats "
            f"let its error move), so a flagged run widens the band rather than being dropped.", ""]
