"""Where the host hand-offs of measured runs spend their time: one table per run.

    PYTHONPATH=. python tools/probes/h200_x4/handoff_split.py data/nvidia/h200_x4/handoff_2026-11-27/runs
    PYTHONPATH=. python tools/probes/h200_x4/handoff_split.py data/nvidia/h100_x4/runs \
        --only sf4_1080p_it4000/steady --warmup 0

For each run folder below the given folder (packed archives are read in place), every hand-off
bound by an input is split at the host thread that acted on it (`mgpusim.results.waits.host_split`):
`input seen` from the input's end until the thread had seen all its inputs (a fence wait's wake,
the interpreter's turn), `call` until it called vkQueueSubmit or queued a host copy's parts,
`start` until the task (or a copy's part) began. Also each host copy part's duration. Why: a
model with one dispatch delay per hand-off can only fit one number; this says which hand-offs
take longer, and in which part of the wait.

The runs of 2026-11-27 (4x H200, sort-first on 4 GPUs; data/nvidia/h200_x4/handoff_2026-11-27)
were made with:

    mgpusim run experiments/h200_x4/sort_first.toml --set schedule.frames=150 \\
        --set schedule.warmup_frames=30 --devices 0,1,2,3 [--set ...] --out runs/NAME
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from mgpusim.measure import run_archive
from mgpusim.results.waits import host_split
from mgpusim.validation.measured import read_submissions
from mgpusim.validation.measured_check import read_table


def split_table(folder: Path, trace: pd.DataFrame, warmup: int) -> pd.DataFrame:
    """One row per hand-off of the run in `folder` (its `trace`), frames before `warmup` left
    out; mean ms."""
    submissions = read_submissions(folder)
    if submissions is None:
        raise SystemExit(f"{folder}: no submissions table (a run older than 2026-11-25)")
    table = pd.DataFrame(host_split(trace, submissions, warmup)).T
    return table.rename(columns={"input_seen_ms": "input seen", "submit_call_ms": "call",
                                 "device_start_ms": "start"})


def part_ms(trace: pd.DataFrame, warmup: int) -> pd.Series:
    """The durations of a run's host-copy parts (ms), from its `trace`."""
    parts = trace[(trace["step"] == "host_copy") & (trace["frame"] >= warmup)]
    return (parts["end_ns"] - parts["start_ns"]) / 1e6


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", type=Path, help="a folder of measured runs (packed or not)")
    p.add_argument("--warmup", type=int, default=30, help="frames to leave out (default 30)")
    p.add_argument("--only", default="", help="the runs whose folder path contains this")
    args = p.parse_args(argv)
    for folder in run_archive.runs_in(args.runs):
        if args.only not in folder.as_posix():
            continue
        trace = read_table(folder / run_archive.TRACE_NAME)
        print(folder.relative_to(args.runs).as_posix())
        print(split_table(folder, trace, args.warmup).round(3).to_string())
        parts = part_ms(trace, args.warmup)
        if len(parts):
            print(f"host-copy parts: {len(parts)}, median {parts.median():.3f} ms, "
                  f"90th percentile {parts.quantile(0.9):.3f} ms")
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
