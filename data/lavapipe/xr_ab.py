"""Shared by the XR A/B probes in this folder (`*_2026-11-26/ab_probe.py`): run
`experiments/lavapipe/xr.toml` alternating two variants run by run, and split each run's
input-bound render hand-offs. Not part of the package.

Why alternate: on a drifting machine two variants measured one after the other differ by the
drift; alternated run by run (the order flipping every pair) the drift falls on both alike.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Sequence

import pandas as pd

from mgpusim.cli import main
from mgpusim.results.waits import _ready_rows


def split(folder: Path) -> dict[str, float]:
    """One run's frame time, latency, and the median hand-off of its renders bound by another
    GPU's task, in us from that task's end: `seen_us` until the submit thread had seen all
    inputs, `start_us` until the render started."""
    trace, subs = pd.read_csv(folder / "trace.csv"), pd.read_csv(folder / "submissions.csv")
    rows = _ready_rows(trace, 1)
    rows = rows[(rows.binding != "queue") & (rows.step == "render")]
    rows = rows.merge(subs[["frame", "task", "inputs_seen_ns"]], on=["frame", "task"])
    summary = json.loads((folder / "summary.json").read_text())
    return {"frame_ms": summary["frame_time_ms"], "latency_ms": summary["latency_ms"],
            "handoffs": len(rows),
            "seen_us": float((rows.inputs_seen_ns - rows.ready_ns).median() / 1e3),
            "start_us": float((rows.start_ns - rows.ready_ns).median() / 1e3)}


def run_xr(out: Path, sets: Sequence[str]) -> dict[str, float]:
    """One 60-frame XR run with `sets` overrides, 8 rasterizer threads per GPU, split."""
    sets = [*sets, "schedule.frames=60"]
    rc = main(["run", "experiments/lavapipe/xr.toml", *[a for s in sets for a in ("--set", s)],
               "--lp-threads", "8", "--out", str(out)])
    assert rc == 0, rc
    return split(out)


def alternate(root: Path, pairs: int, cases: dict[str, Sequence[str]], variants: tuple[str, str],
              use: Callable[[str], None]) -> pd.DataFrame:
    """`pairs` pairs of runs per case, `use(variant)` before each; the first variant runs
    first in even pairs, second in odd ones. One row per run, also written to root/ab.csv."""
    rows = []
    for i in range(pairs):
        for case, sets in cases.items():
            for variant in (variants if i % 2 == 0 else variants[::-1]):
                use(variant)
                r = run_xr(root / f"{case}_{i}_{variant}", sets)
                rows.append({"pair": i, "case": case, "variant": variant, **r})
    df = pd.DataFrame(rows)
    df.to_csv(root / "ab.csv", index=False)
    return df
