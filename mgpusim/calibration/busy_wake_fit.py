"""The busy_wake effect measured on the calibration runs' traces.

On a host whose cores emulate several GPUs (lavapipe), a GPU's pass that keeps every core busy
wakes its rasterizer threads when it starts. A copy of another GPU whose thread is woken in the
first moments of that pass is often placed behind those threads on one core, and waits there
while the other core sits idle, for a few scheduler ticks or until the pass is done: the pass
runs on one core and the copy starts late. Where it happens the hand-off chain of alternate-frame rendering, particle
offload and pipelining stalls; the model, whose woken threads get a fair share of the cores at
once, had none of it. How often it happens, and how long the copy waits, are properties of the
host's scheduler: they are measured per (pass, other GPU) pair, with the definitions the model
applies (mgpusim.sim.busy_wake)."""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from mgpusim.calibration.run_fit import Run, tasks_by_name
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import CopyTask, PassTask
from mgpusim.results.waits import LONG_WAIT_NS, ready_times
from mgpusim.sim.busy_wake import FILLS_CORES
from mgpusim.sim.executors import task_cores

#: A copy is left behind when its delay is over this (the model's own hand-off gaps on lavapipe
#: are 0.1-0.3 ms) and over LONG_WAIT_NS or half the pass's remaining time, whichever is less.
LEFT_BEHIND_NS = 500_000
#: A left-behind copy whose pass ran on this much longer than its delay waited its full time
#: (it was not let go by the pass ending): the waits `ns` is measured on.
OUTLASTED_NS = 1_000_000


@dataclass(frozen=True)
class BusyWake:
    """The measured effect: of `pairs` (young pass, other GPU with a copy made ready in its
    window), the `share` whose first such copy was left behind; `ns`, how long such a copy
    waits beyond the others' delay when the pass outlasts the wait (`full_waits` such pairs;
    when none, all left-behind pairs, a low estimate since short passes let their copies go)."""
    share: float
    ns: int
    pairs: int
    full_waits: int


def fit_busy_wake(runs: Sequence[Run], profile_data: Mapping[str, Any],
                  window_ns: int) -> BusyWake | None:
    """The busy_wake share and wait over the multi-GPU runs' steady frames (None where no copy
    was made ready within `window_ns` of another GPU's core-filling pass starting).

    A copy's delay is its end less its ready time (every input and its queue's previous task
    ended) less the run's median duration of that copy: a thread left behind shows either as a
    late start or as a copy stretched over the wait (its slice recorded before the stall). It
    is left behind when the delay is over LEFT_BEHIND_NS and over LONG_WAIT_NS or half the
    pass's remaining time (its end less the copy's ready time) if less: a short pass lets the
    copy go when it ends (the model cuts the wait there too)."""
    profile = parse_profile(copy.deepcopy(dict(profile_data)), "<calibration>")
    pairs: list[tuple[int, int]] = []
    for exp, trace in runs:
        if exp.schedule.gpus < 2:
            continue
        tasks = tasks_by_name(exp)
        filling = {name for name, t in tasks.items() if isinstance(t, PassTask)
                   and task_cores(profile, t) >= FILLS_CORES * profile.host.cpu_cores}
        copies = {name for name, t in tasks.items() if isinstance(t, CopyTask)}
        steady = trace[trace["frame"] >= exp.schedule.warmup_frames].reset_index(drop=True)
        pairs += young_pass_delays(steady, filling, copies, window_ns)
    if not pairs:
        return None
    return _left_behind(*(np.asarray(x, dtype=np.int64) for x in zip(*pairs)))


def _left_behind(delay: np.ndarray, left: np.ndarray) -> BusyWake:
    """The share and wait from each pair's (delay, the pass's remaining time)."""
    behind = (delay > LEFT_BEHIND_NS) & (2 * delay > np.minimum(left, 2 * LONG_WAIT_NS))
    if not behind.any():
        return BusyWake(0.0, 0, len(delay), 0)
    full = behind & (left - delay > OUTLASTED_NS)
    waits = delay[full] if full.any() else delay[behind]
    base = np.median(delay[~behind]) if (~behind).any() else 0
    return BusyWake(float(behind.mean()), int(max(0, waits.mean() - base)), len(delay),
                    int(full.sum()))


def young_pass_delays(trace: pd.DataFrame, filling: set[str], copies: set[str],
                      window_ns: int) -> list[tuple[int, int]]:
    """Per (young pass, other device) pair of one run, (delay, the pass's remaining time) in ns
    of the first copy of that device made ready within `window_ns` after a `filling` pass
    lasting at least `window_ns` started (the youngest such pass if several)."""
    ready = ready_times(trace)["ready_ns"]
    fills = trace[trace["task"].isin(filling)
                  & (trace["end_ns"] - trace["start_ns"] >= window_ns)]
    f_dev = fills["device"].to_numpy()
    f_start, f_end = fills["start_ns"].to_numpy(np.int64), fills["end_ns"].to_numpy(np.int64)
    rows = trace[trace["task"].isin(copies) & ready.notna()]
    median = (rows["end_ns"] - rows["start_ns"]).groupby(rows["task"]).median()
    first: dict[tuple[int, str], tuple[float, int, int]] = {}
    row: Any  # a row's fields (pandas-stubs types each as any scalar)
    for idx, row in zip(rows.index, rows.itertuples()):
        at = ready[idx]
        young = np.flatnonzero((f_dev != row.device) & (f_start <= at)
                               & (at - f_start <= window_ns) & (f_end > at))
        if not len(young):
            continue
        j = int(young[np.argmax(f_start[young])])
        pair = (j, str(row.device))
        if pair not in first or at < first[pair][0]:
            first[pair] = (at, int(row.end_ns - at - median[row.task]), int(f_end[j] - at))
    return [(delay, left) for _at, delay, left in first.values()]
