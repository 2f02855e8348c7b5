"""Where a measured timeline loses time against the simulated one: the hand-off gaps.

    python tools/probes/lavapipe/handoff_gaps.py [--from-frame F] RUN_OR_SIM ...

Each argument is a folder with a trace.csv: a `mgpusim run --out` folder (measured) or a
`mgpusim simulate --format csv --out` folder (simulated). For every dependency of the
schedule (a task's `waits_for`, e.g. `-2:present -> render.fragment_loop`) and for one task
after the one before it in the same frame (`out.d2h => out.h2d`), it prints how long the
consumer started after its producer ended (count, mean, median, 90th percentile, max, in ms),
then the wait of each task from the moment it was ready by what ended last (mgpusim.results.waits,
which `mgpusim validate` reports too), each task's duration and the share of time with 0, 1,
2... render passes running. Frames before `--from-frame` (default 40) are left out. Why: the two
traces name the same tasks, so a gap that is 0.3 ms in the model and 2 ms on the machine points
at the hand-off that the model gets wrong, where the frame time alone only says that something
does.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from mgpusim.results.waits import parse_waits_for, ready_waits
from mgpusim.validation.compare import steady_summary


def load(folder: Path, from_frame: int) -> pd.DataFrame:
    trace = pd.read_csv(folder / "trace.csv")
    return trace[trace.frame >= from_frame].copy()


def dependency_gaps(trace: pd.DataFrame) -> pd.DataFrame:
    """One row per (edge, gap_ms): a waits_for dependency or the previous task of the frame."""
    ends = {(r.frame, r.task): r.end_ns for r in trace.itertuples()}
    rows = []
    for r in trace.itertuples():
        for offset, task in parse_waits_for(r.waits_for):
            end = ends.get((r.frame + offset, task))
            if end is not None:
                rows.append((f"{offset}:{task} -> {r.task}", (r.start_ns - end) / 1e6))
    for _, frame in trace.sort_values("start_ns").groupby("frame"):
        tasks = list(frame.itertuples())
        rows += [(f"{a.task} => {b.task}", (b.start_ns - a.end_ns) / 1e6)
                 for a, b in zip(tasks, tasks[1:])]
    return pd.DataFrame(rows, columns=["edge", "gap_ms"])


def render_concurrency(trace: pd.DataFrame) -> dict[int, float]:
    """Share of the traced time with k render passes running at once."""
    renders = trace[trace.step == "render"]
    events = sorted([(s, 1) for s in renders.start_ns] + [(e, -1) for e in renders.end_ns])
    if not events:
        return {}
    spent: dict[int, int] = {}
    running, last = 0, events[0][0]
    for t, step in events:
        spent[running] = spent.get(running, 0) + t - last
        running, last = running + step, t
    total = sum(spent.values()) or 1
    return {k: round(v / total, 3) for k, v in sorted(spent.items())}


def summary(values: pd.Series) -> pd.DataFrame:
    return values.agg(["count", "mean", "median", lambda v: v.quantile(0.9), "max"]).set_axis(
        ["count", "mean", "median", "p90", "max"], axis=1).round(3)


def report(folder: Path, from_frame: int) -> str:
    trace = load(folder, from_frame)
    if trace.empty:
        raise SystemExit(f"{folder}: no frames from {from_frame} on in trace.csv")
    gaps = dependency_gaps(trace)
    trace["dur_ms"] = (trace.end_ns - trace.start_ns) / 1e6
    period = steady_summary(trace, 0)["frame_time_ms"]  # the trace starts at --from-frame
    return "\n".join([
        f"== {folder}: {period:.3f} ms between presents; render passes running at once "
        f"(share of time): {render_concurrency(trace)}",
        "gaps after each dependency (ms):", summary(gaps.groupby("edge").gap_ms).to_string(),
        "waits from ready to start, by what ended last (ms):",
        summary(ready_waits(trace).assign(gap_ms=lambda w: w.wait_ns / 1e6).groupby("edge").gap_ms).to_string(),
        "durations (ms):", summary(trace.groupby(["device", "task"]).dur_ms).to_string(), ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--from-frame", type=int, default=40)
    args = parser.parse_args(argv)
    for folder in args.folders:
        if not (folder / "trace.csv").is_file():
            parser.error(f"{folder}: no trace.csv (simulate with --format csv)")
        print(report(folder, args.from_frame))
    return 0


if __name__ == "__main__":
    sys.exit(main())
