"""The replay level of a cross-validation: a measured run against the model's timeline on the
run's own task durations (:mod:`mgpusim.sim.replay`).

A measured run is compared twice. The *prediction* level runs the calibrated cost model; its
error mixes cost and timeline. The *replay* level gives every task its measured duration, so
what is left is the timeline's error (dependencies, queues, copies, hand-offs), which a noisy
machine cannot move: a large prediction error with a small replay error is the cost model's
(or the machine's speed of the moment), a large replay error is a missing timeline effect.
"""
from __future__ import annotations

from typing import Any, Iterable, Mapping, cast

import pandas as pd

from mgpusim.model.tasks import QueueRef
from mgpusim.schedules.experiment import Experiment
from mgpusim.sim.replay import replay
from mgpusim.validation.compare import compare

#: The hand-offs kept in the replay's report, largest difference first.
SHOWN_WAITS = 3


def measured_durations(trace: pd.DataFrame) -> tuple[dict[tuple[int, str], int], int]:
    """(frame, task) -> ns the run measured for it, and the run's number of frames. A host
    copy has a row per memcpy-thread part: the longest part is its duration (the parts run at
    once, and the copy is done when the last one is)."""
    frame = trace["frame"].to_numpy()
    took = (trace["end_ns"] - trace["start_ns"]).groupby([trace["frame"], trace["task"]]).max()
    # keys (frame, task): the two levels of the index (pandas-stubs types a key as Hashable)
    durations = {(int(f), str(t)): int(ns) for (f, t), ns in cast(Iterable[tuple[tuple[Any, Any], Any]], took.items())}
    return durations, int(frame.max()) + 1 if len(frame) else 0


def replay_comparison(exp: Experiment, measured: pd.DataFrame,
                      queues: Mapping[QueueRef, QueueRef] | None = None) -> tuple[dict[str, Any], pd.DataFrame]:
    """The replay level's side of a report (the replayed frame time and latency, their errors
    against the measured run, and the hand-offs whose waits differ most), and the replayed
    trace. `queues`: the queues the run replaced by another (their tasks ran there)."""
    durations, frames = measured_durations(measured)
    result = replay(exp, durations, frames, queues)
    r = compare(measured, result.trace, exp.schedule.warmup_frames)
    return {"simulated": r["simulated"], "frame_time_error": r["frame_time_error"],
            "latency_error": r["latency_error"],
            "waits": dict(list(r["waits"].items())[:SHOWN_WAITS])}, result.trace
