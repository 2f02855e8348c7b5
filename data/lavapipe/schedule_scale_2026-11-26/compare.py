"""Per-configuration frame-time errors of offline refits, before and after, in one CSV; and the
per-schedule median / worst |error| of each.

    python compare.py OUT.csv JOB=BEFORE_DIR,AFTER_DIR ...

Each DIR is an `mgpusim study validate --held-out` output folder (errors_calibration.csv,
errors_held-out.csv)."""
from __future__ import annotations

import sys

import pandas as pd


def errors(folder: str) -> pd.DataFrame:
    parts = []
    for half in ("calibration", "held-out"):
        e = pd.read_csv(f"{folder}/errors_{half}.csv")
        parts.append(e.assign(set=half))
    return pd.concat(parts)[["set", "config", "schedule", "measured_frame_ms", "frame_time_error",
                             "latency_error"]]


def summary(df: pd.DataFrame, column: str) -> pd.DataFrame:
    a = df.assign(a=df[column].abs() * 100)
    by = a.groupby(["set", "schedule"]).a.agg(["count", "median", "max"])
    total = a.groupby("set").a.agg(["count", "median", "max"]).assign(schedule="all")
    return pd.concat([by, total.set_index("schedule", append=True)]).round(1)


def main(out: str, pairs: list[str]) -> None:
    rows = []
    for pair in pairs:
        job, dirs = pair.split("=")
        before, after = dirs.split(",")
        b, a = errors(before), errors(after)
        m = b.merge(a, on=["set", "config", "schedule", "measured_frame_ms"], suffixes=("_before", "_after"))
        rows.append(m.assign(job=job))
        print(f"== {job}: |frame-time error| %, before -> after (count, median, max)")
        s = pd.merge(summary(m, "frame_time_error_before"), summary(m, "frame_time_error_after"),
                     left_index=True, right_index=True, suffixes=("", "_after"))
        print(s.to_string())
    pd.concat(rows).round(4).to_csv(out, index=False)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
