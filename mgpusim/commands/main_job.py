"""`mgpusim main [--out DIR] [--held-out] [--repeats R] [--run-seconds S]`: measure,
calibrate and validate on lavapipe, and write a report."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import tomli_w

from ..calibrate import apply, calibrate, lavapipe_base, read_measurements, report
from ..calibrate.runs import fit_host_effects, fit_passes_from_runs, fit_task_gap, with_pass_fits
from ..mainjob import (CALIBRATION, HELD_OUT, MAIN_CONFIGS, load_runs, measure_all, measure_configs,
                       with_run_length,
                       validate_saved, write_report)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="the main job: measure, calibrate, validate on lavapipe, write a report")
    p.add_argument("--out", type=Path, default=Path("out/main"), help="output folder (default: out/main)")
    p.add_argument("--held-out", action="store_true",
                   help="also validate 10 held-out configurations (GPU counts, sizes, loads, variants)")
    p.add_argument("--repeats", type=int, default=3, help="measured runs per configuration (their steady window is compared)")
    p.add_argument("--run-seconds", type=float, default=1.5,
                   help="timed length of each measured run (frames are added to reach it)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    t0 = time.monotonic()

    def progress(msg: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    tables = measure_all(out / "measurements", progress)
    df, machine = read_measurements(list(tables))
    cal = calibrate(df, machine)
    data = apply(cal, lavapipe_base(machine), "mgpusim main")
    base = out / "profile_microbenchmarks.toml"
    base.write_text(tomli_w.dumps(data))
    calibration = with_run_length(CALIBRATION, base, args.run_seconds)
    held = with_run_length(HELD_OUT, base, args.run_seconds) if args.held_out else []
    chosen = measure_configs(calibration + held, base, out / "runs", args.repeats, progress)
    progress("calibrate from runs")
    runs = load_runs(calibration, chosen, base)
    data, run_lines = calibrate_from_runs(data, runs)
    profile = out / "profile.toml"
    profile.write_text(tomli_w.dumps(data))
    fit_text = "\n".join([report(cal)] + run_lines)
    result_tables = {"Calibration runs (seen by the fit)": validate_saved(
        calibration, chosen, profile, out / "validation", progress)}
    if held:
        result_tables["Held-out runs (never seen by the fit)"] = validate_saved(
            held, chosen, profile, out / "validation", progress)
    path = write_report(out, result_tables, fit_text)
    print(path.read_text())
    progress(f"done: {path} (main 2-GPU configurations: {', '.join(c.name for c in MAIN_CONFIGS)})")
    return 0


def calibrate_from_runs(data: dict[str, Any], runs: list) -> tuple[dict[str, Any], list[str]]:
    """The profile refined on the calibration runs (pass costs and queue gap from 1-GPU runs,
    host effects by grid search), and the report's lines about it."""
    pass_fits = fit_passes_from_runs(runs)
    data = with_pass_fits(data, pass_fits)
    gap = fit_task_gap(runs)
    if gap is not None:
        for gpu in data["gpus"]:
            gpu["task_gap_ns"] = gap
    host_fit, score = fit_host_effects(data, runs)
    data["host"].update(host_fit)
    data["sources"]["runs"] = ("pass costs and task_gap_ns from 1-GPU runs of the runner; host "
                               "dispatch_ns, submit_ns and oversubscribed_efficiency by a grid search "
                               "on the calibration runs' frame-time error")
    lines = ["refitted on 1-GPU runs:"]
    for kind, f in pass_fits.items():
        terms = ", ".join(f"{n}={v:.4g}+-{e:.2g}" for n, v, e in zip(f.names, f.coef, f.stderr))
        warn = f" ({'; '.join(f.warnings)})" if f.warnings else ""
        lines.append(f"  {kind}: {terms}; rms {f.rel_rms:.1%}{warn}")
    lines += [f"queue task_gap_ns = {gap} (median idle between tasks of a queue, 1-GPU runs)",
              f"host {host_fit} (mean |frame error| {score:.1%} on the calibration runs)"]
    return data, lines
