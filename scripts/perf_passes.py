"""Which threads ran on the host's cores during each pass of a measured lavapipe run.

A lavapipe "GPU" is a set of rasterizer threads on the host's cores, so when a pass takes longer
than its microbenchmark the question is what the cores were doing. Record the scheduler's
context switches on the host clock while the run executes, then read them against the run's
trace:

    perf record -e sched:sched_switch -a -k mono -o sched.data -- \
        .venv/bin/mgpusim run EXPERIMENT.toml --out RUN
    .venv/bin/python scripts/perf_passes.py sched.data RUN [TASK,TASK,...]

For every pass (or every task named) it prints its measured duration, the time each core sat
idle during it, and the on-CPU time of every thread that ran in it. A pass that ran on one core
while the other sat idle shows up as idle time close to its duration with its rasterizer
threads' CPU time adding up to that duration. On the 2-core VM perf loses some of one core's
switches out of idle (the next switch names a thread that was never switched in); the script
counts them per core, and that core's idle time is then a lower bound.
"""
from __future__ import annotations

import collections
import json
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd

SWITCH = re.compile(r"\[(\d+)\]\s+([\d.]+):\s+prev_comm=(.*?) prev_pid=(\d+) .*?"
                    r"==> next_comm=(.*?) next_pid=(\d+)")


def on_cpu_intervals(data: str) -> tuple[dict[tuple[int, int], list], dict[int, str],
                                         collections.Counter]:
    """(cpu, tid) -> [(start_ns, end_ns)] of every stretch a thread ran (tid 0: idle), thread
    names, and per cpu the switches whose switch-in was not recorded (those stretches are
    left out)."""
    text = subprocess.run(["perf", "script", "-i", data, "-F", "cpu,time,trace"],
                          capture_output=True, text=True, check=True).stdout
    spans: dict[tuple[int, int], list] = collections.defaultdict(list)
    names: dict[int, str] = {}
    current: dict[int, tuple[int, int]] = {}
    unmatched: collections.Counter = collections.Counter()
    for line in text.splitlines():
        m = SWITCH.search(line)
        if not m:
            continue
        cpu, t = int(m[1]), round(float(m[2]) * 1e9)
        prev, nxt = int(m[4]), int(m[6])
        names[prev], names[nxt] = m[3], m[5]
        if cpu in current and current[cpu][0] == prev:
            spans[(cpu, prev)].append((current[cpu][1], t))
        elif cpu in current:
            unmatched[cpu] += 1
        current[cpu] = (nxt, t)
    return spans, names, unmatched


def overlap_ms(spans: list, start: int, end: int) -> float:
    return sum(max(0, min(end, b) - max(start, a)) for a, b in spans) / 1e6


def main(data: str, run: str, tasks: str | None = None) -> None:
    spans, names, unmatched = on_cpu_intervals(data)
    for cpu, n in sorted(unmatched.items()):
        print(f"cpu{cpu}: {n} switches without their switch-in; its idle time is a lower bound")
    origin = json.loads((Path(run) / "summary.json").read_text())["clock_origin_ns"]
    trace = pd.read_csv(Path(run) / "trace.csv")
    rows = trace[trace.task.isin(tasks.split(","))] if tasks else trace[trace.step == "render"]
    cpus = sorted({cpu for cpu, _ in spans})
    for r in rows.itertuples():
        start, end = r.start_ns + origin, r.end_ns + origin
        idle = " ".join(f"cpu{c}:{overlap_ms(spans[(c, 0)], start, end):.2f}" for c in cpus)
        used = collections.Counter()
        for (_cpu, tid), s in spans.items():
            if tid:
                used[tid] += overlap_ms(s, start, end)
        busy = " ".join(f"{names[t]}/{t}:{ms:.2f}" for t, ms in used.most_common() if ms >= 0.05)
        print(f"frame {r.frame} {r.device} {r.task} {(end - start) / 1e6:.2f} ms | idle {idle} | {busy}")


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    main(*sys.argv[1:])
