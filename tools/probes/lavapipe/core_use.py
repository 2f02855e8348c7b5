"""How busy the host's cores are in the middle of a run: user, system, idle and steal time.

    python tools/probes/lavapipe/core_use.py [--skip S] [--window W] [--label L] [--csv F] -- \
        mgpusim run EXPERIMENT ... --out OUT

It starts the command, reads /proc/stat (all cores together) and the context-switch count
`skip` seconds later and again `window` seconds after that, waits for the command and prints
one line: the shares of the window's core time and the context switches per second, with the
run's frame time where the command wrote an `--out` folder with a summary.json. `--csv` appends
the line to a table. Choose frames so that the run outlasts skip + window (the line says so
where it did not). Why: a model that shares the cores as a fluid keeps them busy whenever work
is ready; the idle share of a real run says how much of a gap between the two is cores left
waiting rather than work done slower.
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

FIELDS = ("user", "nice", "system", "idle", "iowait", "irq", "softirq", "steal")


def read_stat() -> tuple[list[int], int]:
    """(the all-cores time counters of /proc/stat in FIELDS order, context switches so far)."""
    cpu, ctxt = [], 0
    for line in Path("/proc/stat").read_text().splitlines():
        parts = line.split()
        if parts[0] == "cpu":
            cpu = [int(v) for v in parts[1:1 + len(FIELDS)]]
        elif parts[0] == "ctxt":
            ctxt = int(parts[1])
    return cpu, ctxt


def shares(before: list[int], after: list[int]) -> dict[str, float]:
    """Each counter's share of the time between two readings."""
    spent = [b - a for a, b in zip(before, after)]
    total = sum(spent) or 1
    return {name: value / total for name, value in zip(FIELDS, spent)}


def out_folder(command: list[str]) -> Path | None:
    """The folder the command writes its run to (`--out X`), if it names one."""
    for i, arg in enumerate(command[:-1]):
        if arg == "--out":
            return Path(command[i + 1])
    return None


def frame_time_ms(out: Path | None) -> float | None:
    if out is None or not (out / "summary.json").is_file():
        return None
    return float(json.loads((out / "summary.json").read_text())["frame_time_ms"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip", type=float, default=4.0, help="seconds before the window")
    parser.add_argument("--window", type=float, default=4.0, help="seconds sampled")
    parser.add_argument("--label", default="run")
    parser.add_argument("--csv", type=Path, help="append the line to this table")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to run after --")
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(args.skip)
    cpu0, ctxt0 = read_stat()
    time.sleep(args.window)
    cpu1, ctxt1 = read_stat()
    outlasted = proc.poll() is None
    _, err = proc.communicate()
    if proc.returncode:
        print(err.strip().splitlines()[-1] if err.strip() else "the command failed", file=sys.stderr)
        return proc.returncode
    frame = frame_time_ms(out_folder(command))
    row = {"label": args.label, "frame_time_ms": round(frame, 4) if frame is not None else None,
           **{k: round(v, 4) for k, v in shares(cpu0, cpu1).items()},
           "context_switches_per_s": round((ctxt1 - ctxt0) / args.window),
           "outlasted_window": outlasted}
    print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    if args.csv:
        new = not args.csv.exists()
        with args.csv.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(row))
            if new:
                writer.writeheader()
            writer.writerow(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
