"""A submit thread checking a task's inputs earliest first, against in the listed order, on XR.

The runner checks a node's inputs from other queues earliest submitted first
(`mgpusim.runner.plan.earliest_first`); before, it checked them in the order the task lists them.
This runs `experiments/lavapipe/xr.toml` under strong scaling on 2 and 4 lavapipe GPUs and
under weak scaling on 2 (60 frames, 8 rasterizer threads per GPU), alternating run by run
between `earliest` (the runner as it is) and `listed` (the order patched back from outside), and
writes per run: frame time, latency, and the median hand-off of the renders bound by another
GPU's task (us from that task's end: `seen` until the submit thread had seen all inputs,
`start` until the render started).

    .venv/bin/python data/lavapipe/input_order_2026-11-26/ab_probe.py OUT [PAIRS]

A record of one experiment, not part of the package.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

import mgpusim.runner.plan as plan
from mgpusim.cli import main
from mgpusim.waits import _ready_rows

EARLIEST = plan.earliest_first
CASES = {"strong2": ["schedule.scaling=strong", "schedule.gpus=2"],
         "strong4": ["schedule.scaling=strong", "schedule.gpus=4"],
         "weak2": ["schedule.scaling=weak", "schedule.gpus=2"]}


def split(folder: Path) -> dict[str, float]:
    trace, subs = pd.read_csv(folder / "trace.csv"), pd.read_csv(folder / "submissions.csv")
    rows = _ready_rows(trace, 1)
    rows = rows[(rows.binding != "queue") & (rows.step == "render")]
    rows = rows.merge(subs[["frame", "task", "inputs_seen_ns"]], on=["frame", "task"])
    summary = json.loads((folder / "summary.json").read_text())
    return {"frame_ms": summary["frame_time_ms"], "latency_ms": summary["latency_ms"],
            "handoffs": len(rows),
            "seen_us": float((rows.inputs_seen_ns - rows.ready_ns).median() / 1e3),
            "start_us": float((rows.start_ns - rows.ready_ns).median() / 1e3)}


def run(out: Path, case: str, variant: str) -> dict[str, float]:
    plan.earliest_first = EARLIEST if variant == "earliest" else (lambda dep: 0)
    sets = [*CASES[case], "schedule.frames=60"]
    rc = main(["run", "experiments/lavapipe/xr.toml", *[a for s in sets for a in ("--set", s)],
               "--lp-threads", "8", "--out", str(out)])
    assert rc == 0, rc
    return split(out)


if __name__ == "__main__":
    root, pairs = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 6
    rows = []
    for i in range(pairs):
        for case in CASES:
            order = ("listed", "earliest") if i % 2 == 0 else ("earliest", "listed")
            for variant in order:
                r = run(root / f"{case}_{i}_{variant}", case, variant)
                rows.append({"pair": i, "case": case, "variant": variant, **r})
    df = pd.DataFrame(rows)
    df.to_csv(root / "ab.csv", index=False)
    cols = ["frame_ms", "latency_ms", "seen_us", "start_us"]
    print(df.groupby(["case", "variant"])[cols].median().round(3).to_string())
    ratio = df.pivot_table(index=["case", "pair"], columns="variant", values="frame_ms")
    print((ratio["listed"] / ratio["earliest"]).groupby("case").describe().round(3).to_string())
