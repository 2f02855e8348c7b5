"""Whether a simulated run's frame time and latency had settled by its end.

A summary averages every frame after the warm-up. Where the schedule is still filling up (a
frame pipeline whose latency grows by a copy each frame until its queues are full) that
average is not the steady state, and a short run reports a latency still rising without a
word: a default 60-frame run of `sort_first_tc1` reports 9.0 ms where the run settles at
12.8 ms from frame 92.

**The rule.** Over the frames after the warm-up (the `n` the summary averages), take the last
quarter (`m = floor(n / 4)` frames; for the frame time, the `m` periods between presents that
end in them). A figure (per frame: the latency, or the period since the previous present) has
**settled** when both hold:

  * *no trend at the end*: for some pattern length `p` from 1 to PATTERN_FRAMES (at most
    `m / 2`) frames, every mean of `p` consecutive values over the last quarter lies within
    TOLERANCE (1 %) of the mean of those means (the last quarter's *level*). `p` lets a
    schedule with a repeating pattern settle: AFR on two GPUs presents its frames in pairs, a
    short period and a long one, and only means over two frames are flat;
  * *the summary is the steady state*: the summary's figure (the mean over all `n` frames) lies
    within TOLERANCE of that level.

A run with fewer than MIN_TAIL frames in its last quarter (`n < 16`) is too short to tell, and
counts as not settled. The summary gets `settled` (both figures settled) and `settling`
(`tail_frames`, `frame_time_tail_ms`, `latency_tail_ms`, `frame_time_settled`,
`latency_settled` and `note`, one line saying what has not settled and how far, "" when both
have). The same rule runs on many lanes at once (:func:`settling_arrays`, a sweep's analytic
lanes), so a sweep's row says what the point's own run would.
"""
from __future__ import annotations

from typing import Any

import numpy as np

#: How close the figures must agree (a fraction of the last quarter's mean).
TOLERANCE = 0.01
#: The share of the frames after the warm-up looked at: the end of the run.
TAIL_SHARE = 0.25
#: Fewest frames in that share to tell anything.
MIN_TAIL = 4
#: Longest repeating pattern allowed for (frames).
PATTERN_FRAMES = 8
#: The keys of `settling`, in order.
FIELDS = ("tail_frames", "frame_time_tail_ms", "latency_tail_ms", "frame_time_settled",
          "latency_settled", "note")


def settling(start: np.ndarray, present: np.ndarray, warmup_frames: int) -> dict[str, Any]:
    """The summary's `settling` of one run (per-frame first start and present, ns): what
    :func:`settling_arrays` gives its one lane, computed on the run's own arrays (the same
    numpy reductions over the same values, so the same bits; a fifth of the cost on a short
    run, where the calls, not the values, are the work)."""
    n = len(present) - warmup_frames if len(present) > warmup_frames else 0
    m = int(n * TAIL_SHARE)
    if m < MIN_TAIL:
        lanes = settling_arrays(start.reshape(-1, 1), present.reshape(-1, 1), warmup_frames)
        return {key: _scalar(lanes[key][0]) for key in FIELDS}
    periods = _difference(present[warmup_frames + 1:], present[warmup_frames:-1], in_ints=False)
    latency = _difference(present[warmup_frames:], start[warmup_frames:], in_ints=True)
    ft = _figure_one(periods[-m:], np.add.reduce(periods) / len(periods))
    lat = _figure_one(latency[-m:], np.add.reduce(latency) / n)
    note = _note(m, n, [("frame time", *ft), ("latency", *lat)])
    return {"tail_frames": m, "frame_time_tail_ms": _scalar(ft[0] / 1e6), "latency_tail_ms": _scalar(lat[0] / 1e6),
            "frame_time_settled": bool(ft[2] and ft[3]), "latency_settled": bool(lat[2] and lat[3]), "note": note}


def _difference(later: np.ndarray, earlier: np.ndarray, in_ints: bool) -> np.ndarray:
    """later - earlier (int64 ns) as float64, as :func:`settling_arrays` computes it: in
    integers then converted (`in_ints`), or in floats of the times. A long run's is subtracted
    in place, which gives the same values where every time is below 2^53 ns (each then
    converts exactly, and so does the difference): one 80 MB array less at 10^7 frames."""
    if len(later) < 1 << 16 or max(-int(earlier.min()), int(earlier.max()), -int(later.min()),
                                   int(later.max())) >= 1 << 53:
        if in_ints:
            return (later - earlier).astype(np.float64)
        return later.astype(np.float64) - earlier.astype(np.float64)
    out = later.astype(np.float64)
    for lo in range(0, len(out), 1 << 16):  # (a whole-array cast of `earlier` would be the 80 MB)
        out[lo:lo + (1 << 16)] -= earlier[lo:lo + (1 << 16)]
    return out


def _figure_one(tail: np.ndarray, whole: np.floating) -> tuple[Any, ...]:
    """:func:`_figure` of one lane: (level, whole, flat, agrees), as numpy scalars."""
    m = len(tail)
    sums = np.concatenate((np.zeros(1), np.cumsum(tail)))
    flattest, level = np.inf, np.add.reduce(tail) / m
    for p in range(1, min(PATTERN_FRAMES, m // 2) + 1):
        windows = (sums[p:] - sums[:-p]) / p
        mean = np.add.reduce(windows) / len(windows)
        spread = np.maximum.reduce(np.abs(windows - mean)) / (mean if mean > 0 else 1.0)
        if spread < flattest:
            flattest, level = spread, mean
    agrees = abs(whole - level) / (level if level > 0 else 1.0) <= TOLERANCE
    return level, whole, flattest <= TOLERANCE, agrees


def _scalar(value: Any) -> Any:
    """A lane's value as summary.json keeps it: a Python number, None for an unknown level
    (NaN would make two equal summaries compare unequal)."""
    value = value.item() if isinstance(value, np.generic) else value
    return None if isinstance(value, float) and value != value else value


def settling_arrays(start: np.ndarray, present: np.ndarray, warmup_frames: int) -> dict[str, np.ndarray]:
    """:func:`settling` of many lanes at once: `start` and `present` of shape (frames, lanes);
    one array per key of FIELDS (`note` an array of str)."""
    presents = present[warmup_frames:].astype(np.float64)
    latency = (present - start)[warmup_frames:].astype(np.float64)
    n, lanes = presents.shape
    m = int(n * TAIL_SHARE)
    if m < MIN_TAIL:
        note = (f"only {n} frames after the warm-up: too few to tell whether the frame time and "
                f"latency settled (that takes {int(np.ceil(MIN_TAIL / TAIL_SHARE))}); simulate more "
                "frames (schedule.frames)")
        unknown = np.full(lanes, None, dtype=object)  # no level: null, as summary.json has it
        return {"tail_frames": np.full(lanes, m), "frame_time_tail_ms": unknown, "latency_tail_ms": unknown.copy(),
                "frame_time_settled": np.zeros(lanes, bool), "latency_settled": np.zeros(lanes, bool),
                "note": np.array([note] * lanes, dtype=object)}
    periods = np.diff(presents, axis=0)
    ft = _figure(periods[-m:], periods.mean(axis=0))
    lat = _figure(latency[-m:], latency.mean(axis=0))
    notes = [_note(m, n, [("frame time", *(f[i] for f in ft)), ("latency", *(f[i] for f in lat))])
             for i in range(lanes)]
    return {"tail_frames": np.full(lanes, m), "frame_time_tail_ms": ft[0] / 1e6, "latency_tail_ms": lat[0] / 1e6,
            "frame_time_settled": ft[2] & ft[3], "latency_settled": lat[2] & lat[3],
            "note": np.array(notes, dtype=object)}


def _figure(tail: np.ndarray, whole: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per lane of one figure: the last quarter's level, the summary's mean, whether the last
    quarter is flat and whether the summary agrees with it. The level is the mean of the
    `p`-frame means at the flattest `p`: with a pattern of `p` frames a plain mean over a last
    quarter that is no whole number of patterns would be off by a part of one."""
    m, lanes = tail.shape
    sums = np.vstack([np.zeros((1, lanes)), np.cumsum(tail, axis=0)])
    flattest = np.full(lanes, np.inf)
    level = tail.mean(axis=0)
    for p in range(1, min(PATTERN_FRAMES, m // 2) + 1):
        windows = (sums[p:] - sums[:-p]) / p
        mean = windows.mean(axis=0)
        spread = np.abs(windows - mean).max(axis=0) / np.where(mean > 0, mean, 1.0)
        better = spread < flattest
        flattest, level = np.where(better, spread, flattest), np.where(better, mean, level)
    agrees = np.abs(whole - level) / np.where(level > 0, level, 1.0) <= TOLERANCE
    return level, whole, flattest <= TOLERANCE, agrees


def _note(m: int, n: int, figures: list[tuple[Any, ...]]) -> str:
    """One line on what has not settled ('' where both figures have): a figure still moving
    over the last quarter, or one flat there whose reported mean the frames before still pull."""
    parts = []
    for name, tail, whole, flat, agrees in figures:
        tail_ms, whole_ms = tail / 1e6, whole / 1e6
        if not flat:
            parts.append(f"{name} {_moving(tail, whole)} over the last {m} frames ({tail_ms:.3f} ms "
                         f"there, {whole_ms:.3f} ms reported)")
        elif not agrees:
            parts.append(f"{name} settles at {tail_ms:.3f} ms over the last {m} frames, but the "
                         f"{whole_ms:.3f} ms reported still averages in the frames before")
    if not parts:
        return ""
    return (f"not settled by the end of the run ({n} frames after the warm-up): {'; '.join(parts)}; "
            "simulate more frames (schedule.frames) for the steady state")


def _moving(tail: float, whole: float) -> str:
    if tail > whole * (1 + TOLERANCE):
        return "still rising"
    return "still falling" if tail < whole * (1 - TOLERANCE) else "still moving"
