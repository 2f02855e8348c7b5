"""AFR with the fast-forward over 1-8 GPUs and 10^3-10^7 frames: what a run costs, where its
state repeats, when the event-by-event run itself starts to repeat, and the peak memory of the
longest run.

TC1 AFR (`experiments/afr_tc1.toml`) on N GPUs with N frames in flight (the profile's last GPU
repeated). Per GPU count it prints the CPU time of `simulate()` (the summary read, no trace
kept; best of two) at each length, the repeat the fast-forward found (period, first frame),
and, from an event-by-event run of the same experiment (fast-forward off), the first frame
from which every frame's start and present repeat with that period and shift: the repeat
exists from there, and the fast-forward cannot find it earlier. A fixed pure-Python loop is
timed in the same run, and each time is also given as a multiple of it (the machine's speed
moves 10-130 % within minutes). Last, the longest run once more in a fresh process: its peak
resident set size (VmHWM, what `/usr/bin/time -v` prints of a process started from a small
one), imports included. Every length is read as `schedule.frames` (at most 10^7,
MAX_FRAMES: each of these runs fast-forwards, so it may pass 10^6).

    PYTHONPATH=. python benchmarks/afr_fastforward.py [--gpus 1 2 4 8] [--frames 1000 10000000]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim import load_experiment, simulate  # noqa: E402
from mgpusim.bench.reference import reference_loop  # noqa: E402 - the loop every speed is divided by


def experiment(gpus: int, frames: int):
    return load_experiment(ROOT / "experiments" / "afr_tc1.toml", {
        "schedule.gpus": gpus, "profile.gpu_count": max(gpus, 3), "schedule.frames_in_flight": gpus,
        "schedule.frames": frames})


def cpu_s(gpus: int, frames: int) -> tuple[float, dict]:
    """Fastest CPU seconds of two simulate() calls, and the run's fast_forward summary."""
    best, ff = float("inf"), {}
    for _ in range(2):
        exp = experiment(gpus, frames)
        t0 = time.process_time()
        result = simulate(exp, record_trace=False)
        best = min(best, time.process_time() - t0)
        ff = result.summary["fast_forward"]
    return best, ff


def periodic_from(gpus: int, period: int, shift: int, found: int) -> int:
    """The first frame from which the event-by-event run's frame starts and presents repeat
    every `period` frames, `shift` ns later (in a run twice as long as the fast-forward needed,
    its last frames left out: the end of a run is not periodic)."""
    frames = max(100, 2 * found + 10 * period + 40)
    table = simulate(experiment(gpus, frames), fast_forward=False, record_trace=False).frames
    start, present = table["start_ns"].to_numpy(np.int64), table["present_ns"].to_numpy(np.int64)
    same = (start[period:] - start[:-period] == shift) & (present[period:] - present[:-period] == shift)
    bad = np.flatnonzero(~same[:frames - period - 4 * period - 20])
    return int(bad[-1]) + 1 if len(bad) else 0


def peak_rss(gpus: int, frames: int) -> tuple[float, float]:
    """(CPU s, peak RSS in MiB) of one simulate() of `frames` frames (summary read, no trace
    kept) in a fresh process."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, __file__, "--one", str(gpus), str(frames)], env=env,
                         capture_output=True, text=True, check=True).stdout
    one = json.loads(out.strip().splitlines()[-1])
    return one["cpu_s"], one["peak_mib"]


def one(gpus: int, frames: int) -> None:
    """The child of :func:`peak_rss`: prints one line of JSON."""
    exp = experiment(gpus, frames)
    t0 = time.process_time()
    simulate(exp, record_trace=False).summary  # noqa: B018
    took = time.process_time() - t0
    print(json.dumps({"cpu_s": took, "peak_mib": _peak_mib()}))


def _peak_mib() -> float:
    """This program's peak resident set size: VmHWM, which starts afresh at exec (ru_maxrss
    would also count the parent's memory copied at fork, here the longest runs' hundreds of MB)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # (KiB on Linux)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gpus", type=int, nargs="*", default=[1, 2, 3, 4, 6, 8], help="GPU counts")
    p.add_argument("--frames", type=int, nargs="*", default=[1000, 10_000, 100_000, 1_000_000, 10_000_000],
                   help="run lengths")
    p.add_argument("--no-rss", action="store_true", help="leave out the fresh-process run of the longest")
    p.add_argument("--one", type=int, nargs=2, metavar=("GPUS", "FRAMES"), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.one:
        one(*args.one)
        return
    simulate(experiment(2, 100))  # imports and caches, untimed
    ref = min(reference_loop() for _ in range(3))
    print(f"reference loop: {ref * 1e3:.1f} ms CPU")
    longest = max(args.frames)
    print("GPUs | " + " | ".join(f"{n:>9,} frames" for n in args.frames)
          + " | repeat found (period, from frame) | event-by-event run repeats from"
          + ("" if args.no_rss else f" | {longest:,} frames in a fresh process: CPU, peak RSS"))
    for gpus in args.gpus:
        cells, ff = [], {}
        for frames in args.frames:
            took, ff = cpu_s(gpus, frames)
            cells.append(f"{took * 1e3:7.1f} ms ({took / ref:5.2f}x)")
        found = ff.get("from_frame")
        onset = "-"
        if ff.get("used"):
            onset = str(periodic_from(gpus, ff["period_frames"], ff["period_ns"], found))
        fresh = ""
        if not args.no_rss:
            cpu, peak = peak_rss(gpus, longest)
            fresh = f" | {cpu:.2f} s, {peak:.0f} MiB"
        print(f"{gpus:4d} | " + " | ".join(cells)
              + f" | {ff.get('period_frames', '-')}, {found if found is not None else '-'} | {onset}{fresh}",
              flush=True)
    ref2 = min(reference_loop() for _ in range(3))
    print(f"reference loop after: {ref2 * 1e3:.1f} ms CPU")


if __name__ == "__main__":
    main()
