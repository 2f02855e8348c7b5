"""Cross-validation: the same schedule measured and simulated, compared step by step.

Errors are relative and signed: simulated / measured - 1 (positive = the model is slow).
Both sides go through the same summary code, on the same frames after warm-up.

A stall cannot fool the comparison: a measured frame that took more than STALL_FACTOR times the
mean of the run's other frames (a page fault storm, the machine taking its cores away) is listed in the
report and left out of the measured frame time and latency, unless the model's own run has such
frames too (then they belong to the schedule, and both sides keep them).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from mgpusim.results.summary import frames_from_trace, summarize
from mgpusim.results.waits import compare_waits


def step_means_ns(trace: pd.DataFrame, first_frame: int) -> dict[str, float]:
    """Mean duration of every step over the steady-state frames (one row = one execution;
    host copies: one row per thread part, on both sides)."""
    steady = trace[trace["frame"] >= first_frame]
    dur = steady["end_ns"] - steady["start_ns"]
    return {str(k): float(v) for k, v in dur.groupby(steady["step"]).mean().items()}


def rel_error(simulated: float, measured: float) -> float:
    return float(simulated / measured - 1.0) if measured else float("nan")


def steady_summary(trace: pd.DataFrame, warmup_frames: int,
                   present_step: str = "present") -> dict[str, Any]:
    """Frame time, latency and jitter of one trace after the warm-up (either side)."""
    return summarize(frames_from_trace(trace, present_step), None, warmup_frames)


#: A frame (period between presents) longer than this many times the mean of the run's other
#: frames is a stall.
STALL_FACTOR = 3.0


def long_frames(frames: pd.DataFrame, warmup_frames: int) -> dict[int, float]:
    """Steady frames whose period since the previous present is over STALL_FACTOR times the
    mean period of all steady frames: frame -> its period in ms. The mean, not the median,
    and of all periods, not of the others: AFR presents its GPUs' frames in bursts (on two
    GPUs a short and a long period in turn), so every long one is far over the median, and in
    a short window (five periods: 0.7, 98, 0.6, 90, 0.7 ms) also over 3x the mean of the
    others; against the mean of all, a burst's long period never is, a real stall still is."""
    steady = frames[frames["frame"] >= warmup_frames]
    periods = np.diff(steady["present_ns"].to_numpy(dtype=np.int64))
    if len(periods) < 3:
        return {}
    mean = periods.mean()
    ids = steady["frame"].to_numpy()[1:]
    return {int(f): float(p) / 1e6 for f, p in zip(ids, periods) if p > STALL_FACTOR * mean}


def compare(measured: pd.DataFrame, simulated: pd.DataFrame, warmup_frames: int,
            present_step: str = "present") -> dict[str, Any]:
    """Frame time, latency and per-step mean durations of two traces, with relative errors,
    and each hand-off's mean wait from ready to start on both sides (:mod:`mgpusim.results.waits`).
    `stalls`: the measured frames left out (see the module doc)."""
    m_frames, s_frames = frames_from_trace(measured, present_step), frames_from_trace(simulated, present_step)
    stalls = long_frames(m_frames, warmup_frames)
    if stalls and long_frames(s_frames, warmup_frames):
        stalls = {}  # the schedule's own long frames: the model has them too
    m = summarize(m_frames, None, warmup_frames, leave_out=stalls)
    s = summarize(s_frames, None, warmup_frames)
    m_steps, s_steps = step_means_ns(measured, warmup_frames), step_means_ns(simulated, warmup_frames)
    steps = {k: {"measured_ms": m_steps[k] / 1e6, "simulated_ms": s_steps[k] / 1e6,
                 "error": rel_error(s_steps[k], m_steps[k])}
             for k in sorted(set(m_steps) & set(s_steps))}
    return {
        "measured": {"frame_time_ms": m["frame_time_ms"], "latency_ms": m["latency_ms"],
                     "frame_time_jitter_ms": m["frame_time_jitter_ms"]},
        "simulated": {"frame_time_ms": s["frame_time_ms"], "latency_ms": s["latency_ms"],
                      "frame_time_jitter_ms": s["frame_time_jitter_ms"]},
        "frame_time_error": rel_error(s["frame_time_ms"], m["frame_time_ms"]),
        "latency_error": rel_error(s["latency_ms"], m["latency_ms"]),
        "step_errors": {k: v["error"] for k, v in steps.items()},
        "steps": steps,
        "steps_only_measured": sorted(set(m_steps) - set(s_steps)),
        "steps_only_simulated": sorted(set(s_steps) - set(m_steps)),
        "waits": compare_waits(measured, simulated, warmup_frames),
        "stalls": {"factor": STALL_FACTOR, "frames": {str(f): p for f, p in stalls.items()}},
    }


def error_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """One row per configuration: measured and simulated frame time, latency, errors."""
    table = pd.DataFrame([{
        "config": r["config"], "measured_frame_ms": r["measured"]["frame_time_ms"],
        "simulated_frame_ms": r["simulated"]["frame_time_ms"], "frame_time_error": r["frame_time_error"],
        "measured_latency_ms": r["measured"]["latency_ms"], "simulated_latency_ms": r["simulated"]["latency_ms"],
        "latency_error": r["latency_error"],
        "replay_frame_time_error": r.get("replay_frame_time_error", float("nan")),
        "replay_latency_error": r.get("replay_latency_error", float("nan")),
        "stalled_frames": len(r.get("stalls", {}).get("frames", {})), **_speed_columns(r)}
        for r in rows])
    return table


def _speed_columns(r: dict[str, Any]) -> dict[str, Any]:
    """The speed-normalized columns of a comparison that has them (a lavapipe study's runs)."""
    sp = r.get("speed")
    if not sp:
        return {}
    return {"probe_ratio": sp["probe_ratio"], "probe_disagreement": sp["probe_disagreement"],
            "other_cores": sp["other_cores"], "normalized_frame_time_error": sp["frame_time_error"],
            "normalized_latency_error": sp["latency_error"], "speed_flag": sp["flag"]}


def error_stats(table: pd.DataFrame) -> dict[str, float]:
    err = np.abs(table["frame_time_error"].to_numpy())
    lat = np.abs(table["latency_error"].to_numpy())
    stats = {"configurations": int(len(table)), "median_abs_frame_time_error": float(np.median(err)),
             "worst_abs_frame_time_error": float(err.max()), "median_abs_latency_error": float(np.median(lat)),
             "worst_abs_latency_error": float(lat.max())}
    if "replay_frame_time_error" in table and table["replay_frame_time_error"].notna().all():
        rep = np.abs(table["replay_frame_time_error"].to_numpy())
        rep_lat = np.abs(table["replay_latency_error"].to_numpy())
        stats.update(replay_median_abs_frame_time_error=float(np.median(rep)),
                     replay_worst_abs_frame_time_error=float(rep.max()),
                     replay_median_abs_latency_error=float(np.median(rep_lat)),
                     replay_worst_abs_latency_error=float(rep_lat.max()))
    return {**stats, **_normalized_stats(table)}


def _normalized_stats(table: pd.DataFrame) -> dict[str, Any]:
    """The speed-normalized errors' median and worst over every run with a probe, and how
    many of those runs the speed rule flagged (:meth:`speed_norm.RunSpeed.flag`)."""
    if "normalized_frame_time_error" not in table:
        return {}
    probed = table[table["normalized_frame_time_error"].notna()]
    if probed.empty:
        return {}
    norm = np.abs(probed["normalized_frame_time_error"].to_numpy())
    flags = probed["speed_flag"].fillna("").astype(str).tolist()
    return {"normalized_median_abs_frame_time_error": float(np.median(norm)),
            "normalized_worst_abs_frame_time_error": float(norm.max()),
            "normalized_median_abs_latency_error":
                float(np.median(np.abs(probed["normalized_latency_error"].to_numpy()))),
            "median_probe_ratio": float(probed["probe_ratio"].median()),
            "probed_runs": len(flags), "flagged_runs": sum(1 for f in flags if f)}
