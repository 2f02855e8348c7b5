"""What else ran on this machine's cores while a run was measured: other processes' CPU time
and the hypervisor's steal, from the kernel's counters (/proc/stat) and this process's own.

Why: a speed probe beside a run says how fast the machine was, and speed normalization scales
the whole profile by it. That holds when the machine as a whole slowed (steal, the host's clock:
every instruction slower alike). Another process on the cores is not that: it takes a share of
the cores that a pass filling both loses and a one-thread copy barely feels, so the probe's
slowdown is not the run's. The run's record keeps both figures; the refusal rule
(:mod:`mgpusim.measure.speed_norm`) reads the first.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

STAT = Path("/proc/stat")


@dataclass(frozen=True)
class CpuSample:
    """The machine's busy and steal time and this process's CPU time at one moment, in s."""

    wall_s: float
    busy_s: float
    steal_s: float
    own_s: float


def sample() -> CpuSample | None:
    """The counters now; None where the kernel gives none (not Linux)."""
    try:
        fields = STAT.read_text().splitlines()[0].split()
    except OSError:
        return None
    tick = os.sysconf("SC_CLK_TCK")
    values = [int(v) / tick for v in fields[1:]]
    # user nice system idle iowait irq softirq steal ...
    busy = values[0] + values[1] + values[2] + values[5] + values[6]
    own = os.times()
    return CpuSample(wall_s=own.elapsed, busy_s=busy, steal_s=values[7] if len(values) > 7 else 0.0,
                     own_s=own.user + own.system)


def load_between(before: CpuSample | None, after: CpuSample | None) -> dict[str, float]:
    """Other processes' mean CPU use (cores) and the mean steal (cores) from `before` to
    `after`; NaN for both where either sample is missing or no time passed."""
    nan = float("nan")
    if before is None or after is None or after.wall_s <= before.wall_s:
        return {"other_cores": nan, "steal_cores": nan}
    wall = after.wall_s - before.wall_s
    other = (after.busy_s - before.busy_s) - (after.own_s - before.own_s)
    return {"other_cores": round(max(0.0, other) / wall, 3),
            "steal_cores": round((after.steal_s - before.steal_s) / wall, 3)}
