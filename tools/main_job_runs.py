"""Run the main job several times in a row and tabulate what each one concluded.

Why: the main job must give a verdict on whatever machine runs it, at any time of day; one run
shows nothing about that. This runs `mgpusim main --held-out` N times one after another (each
into its own folder, each timed, with the machine's load before it), then writes one table:
per run its start, wall time, exit status, load, the verdict's half and line, and the replay
and prediction statuses with the prediction's band.

    python tools/main_job_runs.py --runs 10 --out out/main_runs
    python tools/main_job_runs.py --collect out/main_runs --table data/lavapipe/main_job_runs/verdicts.csv

`--collect` tabulates a folder of finished runs (written by this script or by the same loop
in a shell: `index.txt` lines `run start_unix wall_s exit load`).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

INDEX = "index.txt"
COLUMNS = ["run", "start_utc", "wall_s", "exit", "load_before", "half", "replay", "replay_median",
           "replay_worst", "prediction", "prediction_median", "prediction_median_band",
           "prediction_worst", "prediction_worst_band", "flagged_runs", "line"]


def run_jobs(out: Path, runs: int, extra: list[str]) -> None:
    """`runs` main jobs into out/run1..runN, each appended to out/index.txt when it ends."""
    out.mkdir(parents=True, exist_ok=True)
    for i in range(1, runs + 1):
        load = os.getloadavg()[0]
        start = time.time()
        with open(out / f"run{i}.log", "w") as log:
            done = subprocess.run([sys.executable, "-m", "mgpusim", "main", "--held-out",
                                   "--out", str(out / f"run{i}"), *extra], stdout=log, stderr=log)
        wall = round(time.time() - start)
        with open(out / INDEX, "a") as index:
            index.write(f"{i} {int(start)} {wall} {done.returncode} {load:.2f}\n")
        print(f"run {i}: exit {done.returncode} in {wall} s", file=sys.stderr)


def collect(folder: Path) -> pd.DataFrame:
    """One row per finished run listed in folder/index.txt."""
    rows = []
    for line in (folder / INDEX).read_text().splitlines():
        if not line.strip():
            continue
        run, start, wall, code, load = line.split()
        rows.append({"run": int(run), "start_utc": _utc(int(start)), "wall_s": int(wall), "exit": int(code),
                     "load_before": float(load), **verdict_fields(folder / f"run{run}")})
    return pd.DataFrame(rows, columns=COLUMNS)


def verdict_fields(run: Path) -> dict[str, Any]:
    """The verdict of one run's report (verdict.json and errors.json), empty where it wrote none."""
    verdict_file, errors_file = run / "verdict.json", run / "errors.json"
    if not verdict_file.is_file():
        return {**{c: "" for c in COLUMNS[5:-1]}, "flagged_runs": 0, "line": "no verdict written"}
    verdict = json.loads(verdict_file.read_text())
    half = verdict.get("half") or ""
    stats = json.loads(errors_file.read_text()).get(half, {}) if errors_file.is_file() else {}
    chosen = stats.get("verdict", {}) if isinstance(stats, dict) else {}
    prediction = chosen.get("prediction", {})
    band = prediction.get("band", {})
    replay = chosen.get("replay", {})
    return {"half": half, "replay": replay.get("status", ""), "replay_median": _share(replay.get("median")),
            "replay_worst": _share(replay.get("worst")), "prediction": prediction.get("status", ""),
            "prediction_median": _share(prediction.get("median")),
            "prediction_median_band": _band(band.get("median")),
            "prediction_worst": _share(prediction.get("worst")),
            "prediction_worst_band": _band(band.get("worst")),
            "flagged_runs": prediction.get("flagged_runs", 0), "line": verdict.get("line", "")}


def _share(value: Any) -> str:
    return f"{value:.1%}" if isinstance(value, (int, float)) else ""


def _band(pair: Any) -> str:
    if not isinstance(pair, list) or len(pair) != 2:
        return ""
    return f"{pair[0]:.1%} to {pair[1]:.1%}"


def _utc(unix: int) -> str:
    return datetime.fromtimestamp(unix, timezone.utc).strftime("%Y-%m-%d %H:%M")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=10, help="main jobs to run one after another")
    p.add_argument("--out", type=Path, default=Path("out/main_runs"), help="folder of the runs")
    p.add_argument("--collect", type=Path, help="only tabulate this folder of finished runs")
    p.add_argument("--table", type=Path, help="write the table here as CSV (default: print it)")
    args, extra = p.parse_known_args(argv)
    folder = args.collect or args.out
    if args.collect is None:
        run_jobs(args.out, args.runs, extra)
    table = collect(folder)
    if args.table:
        args.table.parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.table, index=False)
    print(table.drop(columns=["line", "half"]).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
