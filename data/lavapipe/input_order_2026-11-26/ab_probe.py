"""A submit thread checking a task's inputs earliest first, against in the listed order, on XR.

The runner checks a node's inputs from other queues earliest submitted first
(`mgpusim.real.runner.plan.earliest_first`); before, it checked them in the order the task lists them.
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

import sys
from pathlib import Path

import mgpusim.real.runner.plan as plan

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from xr_ab import alternate  # noqa: E402 - the shared A/B loop beside this folder

EARLIEST = plan.earliest_first
CASES = {"strong2": ["schedule.scaling=strong", "schedule.gpus=2"],
         "strong4": ["schedule.scaling=strong", "schedule.gpus=4"],
         "weak2": ["schedule.scaling=weak", "schedule.gpus=2"]}


def use(variant: str) -> None:
    plan.earliest_first = EARLIEST if variant == "earliest" else (lambda dep: 0)


if __name__ == "__main__":
    root, pairs = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 6
    df = alternate(root, pairs, CASES, ("listed", "earliest"), use)
    cols = ["frame_ms", "latency_ms", "seen_us", "start_us"]
    print(df.groupby(["case", "variant"])[cols].median().round(3).to_string())
    ratio = df.pivot_table(index=["case", "pair"], columns="variant", values="frame_ms")
    print((ratio["listed"] / ratio["earliest"]).groupby("case").describe().round(3).to_string())
