"""The one trace schema shared by the simulator and the Vulkan runner.

One row per task execution. Times are integer nanoseconds on one clock (simulated time, or
the host clock for measured runs). `waits_for` lists the cross-frame/cross-device
dependencies as ``frame:task`` joined by ``;`` so exporters can draw flow arrows from the
trace alone.
"""
from __future__ import annotations

import functools

import pandas as pd

TRACE_COLUMNS: tuple[str, ...] = (
    "frame", "device", "engine", "step", "task", "start_ns", "end_ns", "bytes", "waits_for",
)
TRACE_DTYPES: dict[str, str] = {
    "frame": "int64", "device": "string", "engine": "string", "step": "string",
    "task": "string", "start_ns": "int64", "end_ns": "int64", "bytes": "int64",
    "waits_for": "string",
}
FRAME_COLUMNS: tuple[str, ...] = ("frame", "start_ns", "present_ns", "latency_ns")


@functools.cache
def _empty_trace() -> pd.DataFrame:
    return pd.DataFrame.from_records([], columns=list(TRACE_COLUMNS)).astype(TRACE_DTYPES)


def make_trace(rows: list[tuple]) -> pd.DataFrame:
    """Build a trace DataFrame from row tuples in TRACE_COLUMNS order, sorted by time."""
    if not rows:  # common (runs without a trace): the empty table is built once
        return _empty_trace().copy()
    df = pd.DataFrame.from_records(rows, columns=list(TRACE_COLUMNS))
    df = df.astype(TRACE_DTYPES)
    return df.sort_values(["start_ns", "end_ns", "device", "engine"], kind="stable").reset_index(drop=True)
