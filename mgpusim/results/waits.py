"""Waits from ready to start: where a timeline loses time without any task running longer.

A task is ready when the inputs its trace row lists (`waits_for`: other frames, other devices,
the host) and the task before it on its queue (same device and engine, in start order) have
ended; the wait is from then to its start. Both sides of a cross-validation name the same
tasks, so a wait that is 0.3 ms in the model and 2 ms on the machine points at the hand-off the
model gets wrong, where the frame time alone only says that something does, and the step
durations say that no step is slower. Dependencies inside one frame between two queues of one
device are not in `waits_for`; such a task's wait counts from an earlier moment, on both sides
alike. Pure: traces in, tables out.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

#: A wait longer than this is a thread left behind: the model's own hand-off gaps are 0.1-0.4
#: ms on lavapipe, a scheduler tick 4 ms at 250 Hz.
LONG_WAIT_NS = 2_000_000


def ready_waits(trace: pd.DataFrame, first_frame: int = 0) -> pd.DataFrame:
    """One row per task of frame >= `first_frame` with a known ready time: `edge` (what ended
    last: ``queue`` for the task before it on its queue, else the input as ``offset:task``,
    then `` -> `` and the task) and `wait_ns` (start - ready; negative where the start was
    recorded before the input's end, as a measured copy slice can be)."""
    rows = _ready_rows(trace, first_frame).sort_values("order", kind="stable")
    return pd.DataFrame({"edge": rows["edge"].to_numpy(object),
                         "wait_ns": rows["start_ns"].to_numpy(np.int64)
                         - rows["ready_ns"].to_numpy(np.int64)})


def _ready_rows(trace: pd.DataFrame, first_frame: int) -> pd.DataFrame:
    """The rows of frame >= `first_frame` with a known ready time, with :func:`ready_times`'
    columns and `edge` (what ended last, then `` -> `` and the task)."""
    trace = trace.reset_index(drop=True)
    ready = ready_times(trace)
    keep = ready["ready_ns"].notna() & (trace["frame"] >= first_frame)
    rows = trace[keep].join(ready[keep])
    return rows.assign(edge=rows["binding"] + " -> " + rows["task"].astype(str))


def ready_times(trace: pd.DataFrame) -> pd.DataFrame:
    """Per trace row (same index): `ready_ns`, when its inputs (`waits_for`) and the task
    before it on its queue (same device and engine, in start order) had all ended (NaN for a
    queue's first task without inputs); `binding`, which of them ended last; `order`, the row's
    place in the queue-by-queue walk (what `ready_waits` lists rows in)."""
    ends: dict[tuple[int, str], int] = {}
    for f, t, e in zip(trace["frame"], trace["task"], trace["end_ns"]):
        key = (int(f), str(t))  # a host copy has a row per thread part: it ends with the last
        ends[key] = max(int(e), ends.get(key, int(e)))
    n = len(trace)
    ready, binding = np.full(n, np.nan), np.full(n, "", dtype=object)
    order = np.full(n, -1, dtype=np.int64)
    codes, parsed = waits_for_codes(trace["waits_for"])
    walk = trace.assign(_pos=np.arange(n), _inputs=codes).sort_values(["start_ns", "end_ns"], kind="stable")
    step = 0
    for _, queue in walk.groupby(["device", "engine"], sort=False):
        previous_end = None
        for pos, frame, inputs, end in zip(queue["_pos"], queue["frame"], queue["_inputs"],
                                           queue["end_ns"]):
            at, bound = previous_end, "queue"
            for offset, name in parsed[inputs]:
                input_end = ends.get((int(frame) + offset, name))
                if input_end is not None and (at is None or input_end > at):
                    at, bound = input_end, f"{offset}:{name}"
            previous_end = int(end)
            order[pos], step = step, step + 1
            if at is not None:
                ready[pos], binding[pos] = at, bound
    return pd.DataFrame({"ready_ns": ready, "binding": binding, "order": order}, index=trace.index)


def waits_for_codes(waits_for: pd.Series) -> tuple[np.ndarray, list[list[tuple[int, str]]]]:
    """(code per row, the (offset, task) pairs of each code): every distinct `waits_for` list
    parsed once (a categorical's categories, else the distinct texts), however many rows
    share it; rows without inputs get the code of an empty list."""
    cat = waits_for if isinstance(waits_for.dtype, pd.CategoricalDtype) else waits_for.astype("category")
    parsed = [parse_waits_for(label) for label in cat.cat.categories] + [[]]
    codes = cat.cat.codes.to_numpy(np.int64)
    return np.where(codes < 0, len(parsed) - 1, codes), parsed


def input_edges(waits_for: pd.Series) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every input the rows list, as arrays: (row position, frame offset, input task name).
    Linear in rows plus distinct lists (no text handled per row)."""
    codes, parsed = waits_for_codes(waits_for)
    counts = np.array([len(p) for p in parsed], dtype=np.int64)
    offsets = np.array([o for p in parsed for o, _ in p], dtype=np.int64)
    names = np.array([t for p in parsed for _, t in p], dtype=object)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per_row = counts[codes]
    rows = np.repeat(np.arange(len(codes)), per_row)
    within = np.arange(len(rows)) - np.repeat(np.cumsum(per_row) - per_row, per_row)
    flat = first[codes[rows]] + within
    return rows, offsets[flat], names[flat]


def parse_waits_for(waits_for: Any) -> list[tuple[int, str]]:
    """`waits_for` (``-2:present;0:out.d2h``) as (frame offset, task) pairs."""
    if not isinstance(waits_for, str) or not waits_for:
        return []
    out = []
    for item in waits_for.split(";"):
        offset, name = item.split(":", 1)
        out.append((int(offset), name))
    return out


def wait_stats(trace: pd.DataFrame, first_frame: int) -> dict[str, dict[str, float]]:
    """Per edge: how many waits, their mean (ms) and the share longer than LONG_WAIT_NS."""
    waits = ready_waits(trace, first_frame)
    return {str(edge): {"count": int(len(w)), "mean_ms": float(w.mean() / 1e6),
                        "long_share": float((w > LONG_WAIT_NS).mean())}
            for edge, w in waits.groupby("edge")["wait_ns"]}


def compare_waits(measured: pd.DataFrame, simulated: pd.DataFrame,
                  first_frame: int) -> dict[str, dict[str, float]]:
    """Per edge both traces have: measured and simulated mean wait (ms), the measured share of
    long waits, and the difference (measured - simulated, ms), largest first."""
    m, s = wait_stats(measured, first_frame), wait_stats(simulated, first_frame)
    rows = {edge: {"measured_ms": m[edge]["mean_ms"], "simulated_ms": s[edge]["mean_ms"],
                   "difference_ms": m[edge]["mean_ms"] - s[edge]["mean_ms"],
                   "measured_long_share": m[edge]["long_share"], "measured_count": m[edge]["count"]}
            for edge in set(m) & set(s)}
    return dict(sorted(rows.items(), key=lambda kv: (-abs(kv[1]["difference_ms"]), kv[0])))


def host_split(trace: pd.DataFrame, submissions: pd.DataFrame,
               first_frame: int) -> dict[str, dict[str, float]]:
    """Per hand-off bound by an input (not by the task before it on its queue), the measured
    wait split at the submit thread, mean ms: `input_seen_ms` from the input's end until the
    thread had seen all its inputs, `submit_call_ms` from then to its vkQueueSubmit call (its
    own work, and its turn at the interpreter), `device_start_ms` from that call to the task's
    start (the submit itself and the device picking the work up); `count`. Largest wait
    first. Where a model's one `dispatch_ns` is wrong for some hand-offs, this says which part
    of the wait it misses."""
    rows = _ready_rows(trace, first_frame)
    rows = rows[rows["binding"] != "queue"].astype({"task": "string"})
    host = submissions[["frame", "task", "inputs_seen_ns", "submit_ns"]].astype(
        {"frame": "int64", "task": "string"})
    rows = rows.merge(host, on=["frame", "task"], how="inner")
    parts = pd.DataFrame({"edge": rows["edge"],
                          "input_seen_ms": (rows["inputs_seen_ns"] - rows["ready_ns"]) / 1e6,
                          "submit_call_ms": (rows["submit_ns"] - rows["inputs_seen_ns"]) / 1e6,
                          "device_start_ms": (rows["start_ns"] - rows["submit_ns"]) / 1e6,
                          "wait_ms": (rows["start_ns"] - rows["ready_ns"]) / 1e6})
    means = parts.groupby("edge").mean().sort_values("wait_ms", ascending=False, kind="stable")
    counts = parts.groupby("edge").size().to_dict()
    return {str(edge): {"input_seen_ms": float(m.input_seen_ms), "submit_call_ms": float(m.submit_call_ms),
                        "device_start_ms": float(m.device_start_ms), "count": int(counts[edge])}
            for edge, m in means.iterrows()}
