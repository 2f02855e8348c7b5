"""Start-up of the command line: `mgpusim --version` and `mgpusim --help` in a fresh process,
against a bare interpreter (`python -c pass`) timed in the same run, interleaved, so that the
ratio holds however fast the machine is at the moment (a shared VM moves 10-130 % within
minutes). Also `mgpusim simulate --help` and `mgpusim sweep --help`, which import one command's
module each. The command line builds each command's parser only when that command is used
(mgpusim/cli.py), so these cost about one interpreter plus the editable install's finder.

    PYTHONPATH=. python benchmarks/startup.py [--runs 15]

Prints, per command, the median and the fastest wall time of its runs and the median's ratio
to the bare interpreter's median; the target is 0.3 s for --version and --help (the bare
interpreter takes 0.1-0.16 s on the 2-core development VM).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: What is timed: a name and the command line after the interpreter.
CASES = (
    ("bare interpreter", ["-c", "pass"]),
    ("mgpusim --version", ["-m", "mgpusim", "--version"]),
    ("mgpusim --help", ["-m", "mgpusim", "--help"]),
    ("mgpusim simulate --help", ["-m", "mgpusim", "simulate", "--help"]),
    ("mgpusim sweep --help", ["-m", "mgpusim", "sweep", "--help"]),
)


def wall(args: list[str], env: dict[str, str]) -> float:
    """Seconds for one fresh interpreter to run `args` (output discarded)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=15, help="runs of each command, interleaved (default 15)")
    args = p.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    times: dict[str, list[float]] = {name: [] for name, _ in CASES}
    for _name, argv in CASES:  # one untimed run each: the file cache, the .pyc files
        wall(argv, env)
    for _ in range(args.runs):
        for name, argv in CASES:
            times[name].append(wall(argv, env))
    bare = statistics.median(times["bare interpreter"])
    for name, _ in CASES:
        med = statistics.median(times[name])
        print(f"{name:26s} median {med * 1e3:6.1f} ms  fastest {min(times[name]) * 1e3:6.1f} ms  "
              f"{med / bare:4.2f}x the bare interpreter")


if __name__ == "__main__":
    main()
