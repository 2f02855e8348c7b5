"""Export a trace (simulated or measured) as Chrome-trace JSON for ui.perfetto.dev.

One process per GPU and one for the host; one track per queue, engine, host thread or link
direction. Slices that overlap on one engine go on extra tracks (Perfetto would drop them).
Cross-device and cross-frame dependencies (the trace's `waits_for`) become flow arrows.
"""
from __future__ import annotations

from typing import Any

import pandas as pd

from .results import link_track


def chrome_trace(trace: pd.DataFrame, links: pd.DataFrame | None = None,
                 title: str = "mgpusim") -> dict[str, Any]:
    events: list[dict[str, Any]] = []
    pids = _pids(trace, links)
    for dev, pid in pids.items():
        events.append({"ph": "M", "name": "process_name", "pid": pid, "tid": 0, "args": {"name": dev}})
        events.append({"ph": "M", "name": "process_sort_index", "pid": pid, "tid": 0, "args": {"sort_index": pid}})
    tids: dict[tuple[str, str], int] = {}
    slices = _slices(trace, links)
    lanes = _assign_lanes(slices)
    for (dev, track), group in slices.groupby(["device", "track"], sort=True):
        for lane in sorted(set(lanes[group.index])):
            name = track if lane == 0 else f"{track} ({lane + 1})"
            tid = tids.setdefault((dev, name), len(tids) + 1)
            events.append({"ph": "M", "name": "thread_name", "pid": pids[dev], "tid": tid, "args": {"name": name}})
    where: dict[tuple[int, str], dict[str, Any]] = {}
    for idx, row in slices.iterrows():
        lane = int(lanes[idx])
        name = row.track if lane == 0 else f"{row.track} ({lane + 1})"
        ev = {"ph": "X", "name": row.task, "cat": row.step, "pid": pids[row.device],
              "tid": tids[(row.device, name)], "ts": row.start_ns / 1000.0,
              "dur": (row.end_ns - row.start_ns) / 1000.0,
              "args": {"frame": int(row.frame), "step": row.step, "bytes": int(row.bytes)}}
        events.append(ev)
        if row.frame >= 0:
            key = (int(row.frame), str(row.task))
            if key not in where or row.end_ns > where[key]["ts"] * 1000 + where[key]["dur"] * 1000:
                where[key] = ev
    events.extend(_flows(slices, where))
    return {"traceEvents": events, "displayTimeUnit": "ns", "otherData": {"title": title}}


def _pids(trace: pd.DataFrame, links: pd.DataFrame | None) -> dict[str, int]:
    devices = set(trace["device"].astype(str))
    if links is not None and len(links):
        devices |= {link_track(c)[0] for c in links["channel"].astype(str)}
    ordered = sorted(d for d in devices if d != "host") + (["host"] if "host" in devices else [])
    return {d: i + 1 for i, d in enumerate(ordered)}


def _slices(trace: pd.DataFrame, links: pd.DataFrame | None) -> pd.DataFrame:
    df = trace.assign(track=trace["engine"].astype(str), device=trace["device"].astype(str),
                      task=trace["task"].astype(str), step=trace["step"].astype(str))
    cols = ["frame", "device", "track", "step", "task", "start_ns", "end_ns", "bytes", "waits_for"]
    parts = [df[cols]]
    if links is not None and len(links):
        ch = links["channel"].astype(str)
        parts.append(pd.DataFrame({
            "frame": -1, "device": ch.map(lambda c: link_track(c)[0]), "track": ch.map(lambda c: link_track(c)[1]),
            "step": "link", "task": "busy", "start_ns": links["start_ns"], "end_ns": links["end_ns"],
            "bytes": 0, "waits_for": ""}))
    return pd.concat(parts, ignore_index=True)


def _assign_lanes(slices: pd.DataFrame) -> pd.Series:
    """Greedy interval partitioning per (device, track): a slice takes the first free lane."""
    lanes = pd.Series(0, index=slices.index, dtype="int64")
    for _, group in slices.groupby(["device", "track"], sort=False):
        ends: list[int] = []
        for idx, start, end in group.sort_values(["start_ns", "end_ns"])[["start_ns", "end_ns"]].itertuples():
            for lane, last in enumerate(ends):
                if last <= start:
                    ends[lane] = end
                    lanes[idx] = lane
                    break
            else:
                ends.append(end)
                lanes[idx] = len(ends) - 1
    return lanes


def _flows(slices: pd.DataFrame, where: dict[tuple[int, str], dict[str, Any]]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    seen: set[tuple] = set()
    flow_id = 0
    for row in slices[slices["waits_for"].astype(str) != ""].itertuples():
        dst = where.get((int(row.frame), str(row.task)))
        for label in str(row.waits_for).split(";"):
            offset, _, task = label.partition(":")
            src = where.get((int(row.frame) + int(offset), task))
            if src is None or dst is None or (id(src), id(dst)) in seen:
                continue
            seen.add((id(src), id(dst)))
            flow_id += 1
            out.append({"ph": "s", "id": flow_id, "name": "dep", "cat": "dep", "pid": src["pid"],
                        "tid": src["tid"], "ts": src["ts"] + src["dur"]})
            out.append({"ph": "f", "bp": "e", "id": flow_id, "name": "dep", "cat": "dep",
                        "pid": dst["pid"], "tid": dst["tid"], "ts": dst["ts"]})
    return out
