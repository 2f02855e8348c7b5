"""The steady state of a configuration on a noisy machine: a fast window of its measured runs.

Why: the 2-core development machine delivers between one and two cores, in phases of
0.25-2 s that the guest cannot see, so the mean frame time of a whole run depends on which
phases it caught (runs of one configuration differed by up to 80 %). Interference only ever
adds time, so the machine the model describes is the machine in its fast phases. Each run's
frames after the warm-up are cut into consecutive windows of at least WINDOW_MS (and
MIN_PERIODS frame periods; a shorter run is one window); over all runs of the configuration
the window at the QUANTILE of frame time is taken (not the fastest, which a few lucky frames
could set). Between the saved
runs of two full jobs this estimate moved by 2.7 % (median) and 12.8 % (worst), the fastest
whole run by 4.0 % and 23 %; over two other pairs of jobs 2.2 / 21.6 % against 2.7 / 27.2 %
and 1.7 / 7.3 % against 2.1 / 6.3 % (docs/validation.md: how those were computed).

The window's frames, with the warm-up frames just before it, are written as a measured trace
in the runner's schema (frames renumbered from 0), so calibration and validation read it like
any measured run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from mgpusim.model.errors import InputError

WINDOW_MS = 200.0
MIN_PERIODS = 4
QUANTILE = 0.1


@dataclass(frozen=True)
class Window:
    """Frames first..last of run `run`; frame time = (present[last] - present[first]) / periods."""
    run: int
    first: int
    last: int
    frame_time_ms: float


def windows(frames: pd.DataFrame, warmup_frames: int, run: int,
            window_ms: float = WINDOW_MS, min_periods: int = MIN_PERIODS) -> list[Window]:
    """Consecutive windows over one run's steady frames (`frames`: frame, present_ns); a run
    shorter than one window is one window."""
    steady = frames[frames["frame"] >= warmup_frames].sort_values("frame")
    ids, presents = steady["frame"].to_numpy(), steady["present_ns"].to_numpy()
    if len(presents) < 2:
        return []
    mean_period = (presents[-1] - presents[0]) / (len(presents) - 1)
    width = max(min_periods, math.ceil(window_ms * 1e6 / mean_period)) if mean_period > 0 else min_periods
    width = min(width, len(presents) - 1)  # a short run is one window
    out = []
    for start in range(0, len(presents) - width, width):
        end = start + width
        out.append(Window(run, int(ids[start]), int(ids[end]),
                          float(presents[end] - presents[start]) / width / 1e6))
    return out


def pick(candidates: list[Window], quantile: float = QUANTILE) -> Window:
    """The window at `quantile` of frame time (nearest rank)."""
    if not candidates:
        raise InputError("no measured run has two presents after the warm-up",
                         field="schedule.frames")
    ranked = sorted(candidates, key=lambda w: (w.frame_time_ms, w.run, w.first))
    return ranked[max(1, math.ceil(quantile * len(ranked))) - 1]


def window_trace(trace: pd.DataFrame, window: Window, warmup_frames: int) -> pd.DataFrame:
    """The window's frames, after the `warmup_frames` frames that precede it, renumbered so
    that the window starts right after the warm-up: `steady_summary` of the result gives the
    window's frame time."""
    origin = window.first - warmup_frames
    if origin < 0:
        raise InputError(f"window starts at frame {window.first}, inside the warm-up")
    rows = trace[(trace["frame"] >= origin) & (trace["frame"] <= window.last)].copy()
    rows["frame"] = rows["frame"] - origin
    return rows.reset_index(drop=True)
