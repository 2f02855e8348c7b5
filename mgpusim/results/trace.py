"""The one trace schema shared by the simulator and the Vulkan runner.

One row per task execution. Times are integer nanoseconds on one clock (simulated time, or
the host clock for measured runs). `waits_for` lists the cross-frame/cross-device
dependencies as ``offset:task`` joined by ``;`` so exporters can draw flow arrows from the
trace alone. In memory it is a categorical column: an integer code per row and each distinct
list once, because one task of a many-chunk pipeline lists thousands of inputs (a text per
row grew with the square of the chunk count); files hold it dictionary-encoded (Parquet) or
as text (CSV).
"""
from __future__ import annotations

import functools
from typing import Any, Sequence

import numpy as np
import pandas as pd

TRACE_COLUMNS: tuple[str, ...] = (
    "frame", "device", "engine", "step", "task", "start_ns", "end_ns", "bytes", "waits_for",
)
TRACE_DTYPES: dict[str, str] = {
    "frame": "int64", "device": "string", "engine": "string", "step": "string",
    "task": "string", "start_ns": "int64", "end_ns": "int64", "bytes": "int64",
    "waits_for": "category",
}
FRAME_COLUMNS: tuple[str, ...] = ("frame", "start_ns", "present_ns", "latency_ns")
#: A measured run's host side of each GPU task (host clock, as the trace): when its submit
#: thread had seen every input it waits for on the host (another device's fence, a host copy),
#: and when it called vkQueueSubmit and got control back. Splits a hand-off's wait into the
#: thread waking, its own work before the submit, and the device picking the work up.
SUBMISSION_COLUMNS: tuple[str, ...] = (
    "frame", "device", "engine", "task", "inputs_seen_ns", "submit_ns", "submitted_ns",
)


@functools.cache
def _empty_trace() -> pd.DataFrame:
    return pd.DataFrame.from_records([], columns=list(TRACE_COLUMNS)).astype(TRACE_DTYPES)


def make_trace(rows: list[tuple], labels: Sequence[str] | None = None) -> pd.DataFrame:
    """Build a trace DataFrame from row tuples in TRACE_COLUMNS order, sorted by time.
    `labels`: the rows' last column holds task ids, and `labels[id]` is that task's
    `waits_for` text (the simulator's rows, :mod:`mgpusim.schedules.task_inputs`); else the
    last column is the text itself."""
    if not rows:  # common (runs without a trace): the empty table is built once
        return _empty_trace().copy()
    df = pd.DataFrame.from_records(rows, columns=list(TRACE_COLUMNS))
    waits = waits_for_column(df["waits_for"].to_numpy(), labels)
    df = df.drop(columns="waits_for").astype({c: TRACE_DTYPES[c] for c in TRACE_COLUMNS[:-1]})
    df["waits_for"] = waits
    return df.sort_values(["start_ns", "end_ns", "device", "engine"], kind="stable").reset_index(drop=True)


def waits_for_column(values: np.ndarray, labels: Sequence[str] | None = None) -> pd.Categorical:
    """The `waits_for` column as a categorical: from task ids and their labels (each label
    stored once), or from text."""
    if labels is None:
        return pd.Categorical(values)
    codes, uniques = waits_for_categories(labels)
    return pd.Categorical.from_codes(codes[np.asarray(values, dtype=np.int64)], categories=uniques)


def waits_for_categories(labels: Sequence[str] | np.ndarray) -> tuple[np.ndarray, Any]:
    """(code of each id's label, the distinct labels): a categorical's parts, from labels by
    id (several tasks share a label, often the empty one)."""
    codes, uniques = pd.factorize(np.asarray(labels, dtype=object))
    return codes, uniques


def make_submissions(rows: list[tuple]) -> pd.DataFrame:
    """Build a submissions table from row tuples in SUBMISSION_COLUMNS order, by submit time."""
    df = pd.DataFrame.from_records(rows, columns=list(SUBMISSION_COLUMNS))
    df = df.astype({"frame": "int64", "device": "string", "engine": "string", "task": "string",
                    "inputs_seen_ns": "int64", "submit_ns": "int64", "submitted_ns": "int64"})
    return df.sort_values(["submit_ns", "device"], kind="stable").reset_index(drop=True)
