"""Export a trace (simulated or measured) as Chrome trace-event JSON for ui.perfetto.dev.

What the file holds (docs/outputs.md has the reader's version):

- one process per GPU and one for the host, named, in GPU order; one named thread (track)
  per queue, copy engine, host thread and link direction; slices that overlap on one engine
  go on extra tracks ("graphics (2)"), as Perfetto would otherwise drop them;
- a slice per task with its frame, step and bytes in `args`, and one per busy interval of a link;
- flow arrows for the trace's cross-device and cross-frame dependencies (`waits_for`): each
  arrow's start lies strictly inside the slice it leaves and its end strictly inside the slice
  it enters (`"bp": "e"`), so the importer binds them to those slices and never to a
  neighbour that starts where another ends;
- counter tracks: bytes/s on every link direction and host channel (each transfer counted at
  its mean rate over its slice), and the busy fraction of every queue, engine, host thread and
  link per interval of about one frame.

Built column-wise with pandas and numpy (no Python loop over the trace's rows), so a window
of a few hundred frames exports in well under a second.
"""
from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pandas as pd

from mgpusim.results.summary import link_track
from mgpusim.results.waits import input_edges

#: Copy steps whose name is also the path they cross (mgpusim.model.tasks.CopyTask.path).
_PATH_STEPS = ("d2h", "h2d", "d2d")


def chrome_trace(trace: pd.DataFrame, links: pd.DataFrame | None = None,
                 title: str = "mgpusim") -> dict[str, Any]:
    """The trace (and the links' busy intervals) as a Chrome trace-event document."""
    return json.loads(chrome_trace_json(trace, links, title))  # text, not a file


def chrome_trace_json(trace: pd.DataFrame, links: pd.DataFrame | None = None, title: str = "mgpusim") -> str:
    """:func:`chrome_trace` as JSON text, encoded by pandas' C encoder a table at a time."""
    links = links if links is not None and len(links) else None
    slices = _slices(trace, links)
    pids = _pids(slices)
    slices["pid"] = _lookup(slices[["device"]], {(d,): pid for d, pid in pids.items()})
    slices["lane"] = _assign_lanes(slices)
    slices["thread"] = slices["track"].where(slices["lane"] == 0,
                                             slices["track"] + " (" + (slices["lane"] + 1).astype(str) + ")")
    tids = _tids(slices)
    slices["tid"] = _lookup(slices[["device", "thread"]], tids)
    flows = _flows(slices, trace["waits_for"])
    lines = [_metadata(pids, tids), *_slice_events(slices), *flows, *_counters(trace, links, pids, slices)]
    events = ",\n".join(",\n".join(part) for part in lines if len(part))
    other = json.dumps({"title": title})
    return f'{{"traceEvents":[\n{events}\n],"displayTimeUnit":"ns","otherData":{other}}}\n'


def _json_lines(events: pd.DataFrame, args: pd.DataFrame | None = None) -> list[str]:
    """Each row as one JSON object, with the matching row of `args` nested as its "args".
    Built column by column in Arrow (no Python object per field): each distinct string is
    JSON-encoded once, numbers are written by Arrow (floats rounded to 4 decimals first)."""
    if events.empty:
        return []
    import pyarrow.compute as pc  # noqa: PLC0415
    pieces: list[Any] = []
    for opening, table in (("{", events), (',"args":{', args)):
        if table is None:
            continue
        for i, name in enumerate(table.columns):
            pieces.append((opening if i == 0 else ",") + json.dumps(str(name)) + ":")
            pieces.append(_json_column(table[name]))
        if table is args:
            pieces.append("}")
    pieces.append("}")
    return pc.binary_join_element_wise(*pieces, "").to_pylist()


def _json_column(col: pd.Series) -> Any:
    """A column as an Arrow array of JSON texts."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.compute as pc  # noqa: PLC0415
    if pd.api.types.is_integer_dtype(col.dtype):
        return pa.array(col.to_numpy(np.int64)).cast(pa.string())
    if pd.api.types.is_float_dtype(col.dtype):
        numbers = pa.array(np.round(col.to_numpy(np.float64), 4))
        return pc.if_else(pc.is_finite(numbers), numbers.cast(pa.string()), "null")  # JSON has no NaN
    codes, uniques = pd.factorize(col, use_na_sentinel=False)
    encoded = pa.array([json.dumps(None if _missing(u) else str(u)) for u in uniques], type=pa.string())
    return encoded.take(pa.array(codes))


def _missing(value: Any) -> bool:
    return value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value))


# ----- tracks --------------------------------------------------------------------------------
def _slices(trace: pd.DataFrame, links: pd.DataFrame | None) -> pd.DataFrame:
    """Trace rows and link busy intervals in one table, numbered 0..n-1 (a window of a trace
    keeps its row labels; lanes are set by position): the trace's rows first, in its order."""
    trace = trace.reset_index(drop=True)
    df = pd.DataFrame({"frame": trace["frame"].to_numpy(np.int64), "device": trace["device"].astype(str),
                       "track": trace["engine"].astype(str), "step": trace["step"].astype(str),
                       "task": trace["task"].astype(str), "start_ns": trace["start_ns"].to_numpy(np.int64),
                       "end_ns": trace["end_ns"].to_numpy(np.int64), "bytes": trace["bytes"].to_numpy(np.int64)})
    if links is None:
        return df
    ch = links["channel"].astype(str)
    where = pd.DataFrame([link_track(c) for c in ch.unique()], index=ch.unique(), columns=["device", "track"])
    busy = pd.DataFrame({"frame": -1, "device": ch.map(where["device"]).to_numpy(),
                         "track": ch.map(where["track"]).to_numpy(), "step": "link", "task": ch.to_numpy(),
                         "start_ns": links["start_ns"].to_numpy(np.int64),
                         "end_ns": links["end_ns"].to_numpy(np.int64), "bytes": 0})
    return pd.concat([df, busy], ignore_index=True)


def _lookup(keys: pd.DataFrame, table: dict[tuple, int]) -> np.ndarray:
    """`table[row]` for every row of `keys`, looked up once per distinct row."""
    codes = keys.groupby(list(keys.columns), sort=False).ngroup().to_numpy()
    values = [table[tuple(k)] for k in keys.drop_duplicates().itertuples(index=False)]
    return np.asarray(values, dtype=np.int64)[codes]


def _pids(slices: pd.DataFrame) -> dict[str, int]:
    devices = set(slices["device"].unique().tolist())
    ordered = sorted(d for d in devices if d != "host") + (["host"] if "host" in devices else [])
    return {d: i + 1 for i, d in enumerate(ordered)}


def _tids(slices: pd.DataFrame) -> dict[tuple[str, str], int]:
    """Thread ids per (device, track): queues and engines first, then link tracks."""
    tracks = slices[["device", "thread"]].drop_duplicates()
    key = tracks["thread"].str.startswith("link").astype(int).astype(str) + tracks["thread"]
    tracks = tracks.assign(key=key).sort_values(["device", "key"])
    return {(d, t): i + 1 for i, (d, t) in enumerate(zip(tracks["device"], tracks["thread"]))}


def _assign_lanes(slices: pd.DataFrame) -> np.ndarray:
    """Lane 0 for every slice of a track whose slices never overlap (found column-wise);
    greedy interval partitioning, a slice to the first free lane, only on tracks that overlap."""
    lanes = np.zeros(len(slices), dtype=np.int64)
    order = slices.sort_values(["device", "track", "start_ns", "end_ns"], kind="stable")
    same = (order["device"].eq(order["device"].shift()) & order["track"].eq(order["track"].shift())).to_numpy()
    prev_end = order.groupby(["device", "track"], sort=False)["end_ns"].cummax().shift().to_numpy()
    overlaps = same & (order["start_ns"].to_numpy() < np.nan_to_num(prev_end, nan=np.inf))
    bad = order.loc[overlaps, ["device", "track"]].drop_duplicates()
    for dev, track in zip(bad["device"], bad["track"]):
        group = order[(order["device"] == dev) & (order["track"] == track)]
        ends: list[int] = []
        for idx, start, end in zip(group.index, group["start_ns"], group["end_ns"]):
            lane = next((i for i, last in enumerate(ends) if last <= start), len(ends))
            ends[lane:lane + 1] = [end]
            lanes[idx] = lane
    return lanes


def _metadata(pids: dict[str, int], tids: dict[tuple[str, str], int]) -> list[str]:
    out: list[dict[str, Any]] = []
    for dev, pid in pids.items():
        out.append({"ph": "M", "name": "process_name", "pid": pid, "tid": 0, "args": {"name": dev}})
        out.append({"ph": "M", "name": "process_sort_index", "pid": pid, "tid": 0, "args": {"sort_index": pid}})
    for (dev, name), tid in tids.items():
        out.append({"ph": "M", "name": "thread_name", "pid": pids[dev], "tid": tid, "args": {"name": name}})
        out.append({"ph": "M", "name": "thread_sort_index", "pid": pids[dev], "tid": tid,
                    "args": {"sort_index": tid}})
    return [json.dumps(e) for e in out]  # one per track, not per row


def _slice_events(slices: pd.DataFrame) -> list[list[str]]:
    """Task slices with {frame, step, bytes}; link busy intervals with {channel}."""
    out = []
    for is_task, part in slices.groupby(slices["frame"] >= 0, sort=False):
        events = pd.DataFrame({"ph": "X", "name": part["task"] if is_task else "busy", "cat": part["step"],
                               "pid": part["pid"], "tid": part["tid"], "ts": part["start_ns"] / 1000.0,
                               "dur": (part["end_ns"] - part["start_ns"]) / 1000.0})
        args = part[["frame", "step", "bytes"]] if is_task else pd.DataFrame({"channel": part["task"]})
        out.append(_json_lines(events, args))
    return out


# ----- flow arrows ---------------------------------------------------------------------------
def _flows(slices: pd.DataFrame, waits_for: pd.Series) -> list[list[str]]:
    """One arrow per (source task, waiting task) pair, from the source's last-ending slice to
    the waiter's first-starting one; endpoints at the slices' middle nanosecond. `waits_for`:
    the trace's column (its rows are the first slices); each distinct list is parsed once, and
    instances are matched on integer keys (frame, task code)."""
    tasks = slices[(slices["frame"] >= 0) & (slices["end_ns"] - slices["start_ns"] >= 2)]
    if tasks.empty:
        return []
    names = pd.Index(tasks["task"].unique())
    tasks = tasks.assign(key=tasks["frame"].to_numpy(np.int64) * len(names) + names.get_indexer(tasks["task"]))
    src_of = tasks.sort_values("end_ns", kind="stable").drop_duplicates("key", keep="last").set_index("key")
    dst_of = tasks.sort_values("start_ns", kind="stable").drop_duplicates("key", keep="first")
    rows, offset, name = input_edges(waits_for.iloc[dst_of.index.to_numpy()])
    source = names.get_indexer(name)
    frame = dst_of["frame"].to_numpy(np.int64)[rows] + offset
    deps = pd.DataFrame({"dst": dst_of["key"].to_numpy(np.int64)[rows],
                         "src": frame * len(names) + source})[source >= 0].drop_duplicates()
    dst_of = dst_of.set_index("key")
    deps = deps[deps["src"].isin(src_of.index) & deps["dst"].isin(dst_of.index)]
    if deps.empty:
        return []
    src, dst = src_of.loc[deps["src"]], dst_of.loc[deps["dst"]]
    ids = np.arange(1, len(deps) + 1)
    common = {"name": "dep", "cat": "dep", "id": ids}
    starts = pd.DataFrame({"ph": "s", **common, "pid": src["pid"].to_numpy(), "tid": src["tid"].to_numpy(),
                           "ts": _middle(src["start_ns"], src["end_ns"])})
    ends = pd.DataFrame({"ph": "f", "bp": "e", **common, "pid": dst["pid"].to_numpy(), "tid": dst["tid"].to_numpy(),
                         "ts": _middle(dst["start_ns"], dst["end_ns"])})
    return [_json_lines(starts), _json_lines(ends)]


def _middle(start: pd.Series, end: pd.Series) -> np.ndarray:
    """The slice's middle in microseconds, on a whole nanosecond strictly inside it."""
    return (start.to_numpy(np.int64) + (end - start).to_numpy(np.int64) // 2) / 1000.0


# ----- counters ------------------------------------------------------------------------------
def link_rates(trace: pd.DataFrame, links: pd.DataFrame | None) -> pd.DataFrame:
    """Bytes/s on each channel as a step function: (channel, ts_ns, bytes_per_s) at every
    change. A copy crosses `<gpu>.<path>` (its step names the path), a peer copy its GPU's
    peer link, a host copy host memory; each at its mean rate over its slice."""
    moved = trace[(trace["bytes"] > 0) & (trace["end_ns"] > trace["start_ns"])]
    device, step = moved["device"].astype(str), moved["step"].astype(str)
    channel = pd.Series(pd.NA, index=moved.index, dtype="object")
    channel[device == "host"] = "host.memory"
    on_path = (device != "host") & step.isin(_PATH_STEPS)
    channel[on_path] = device[on_path] + "." + step[on_path]
    peer = (device != "host") & (step == "p2p")
    if peer.any():
        channel[peer] = _peer_channels(moved[peer], links)
    moved = moved.assign(channel=channel).dropna(subset=["channel"])
    if moved.empty:
        return pd.DataFrame({"channel": pd.Series(dtype=str), "ts_ns": pd.Series(dtype="int64"),
                             "bytes_per_s": pd.Series(dtype=float)})
    rate = moved["bytes"] * 1e9 / (moved["end_ns"] - moved["start_ns"])
    steps = pd.concat([pd.DataFrame({"channel": moved["channel"], "ts_ns": moved["start_ns"], "delta": rate}),
                       pd.DataFrame({"channel": moved["channel"], "ts_ns": moved["end_ns"], "delta": -rate})])
    steps = steps.groupby(["channel", "ts_ns"], sort=True)["delta"].sum().reset_index()
    steps["bytes_per_s"] = steps.groupby("channel")["delta"].cumsum().clip(lower=0).round(3)
    return steps.drop(columns="delta")


def _peer_channels(rows: pd.DataFrame, links: pd.DataFrame | None) -> pd.Series:
    """The peer link each p2p copy crossed: its GPU's only peer link, else the one that was
    busy when the copy ended."""
    out = pd.Series(None, index=rows.index, dtype=object)
    if links is None:  # no link crossed: none to name
        return out
    channels = links["channel"].astype(str)
    names = sorted(set(channels))
    device = rows["device"].astype(str)
    end = rows["end_ns"].to_numpy(np.int64)
    for dev in device.unique():
        mine = [c for c in names if c.startswith(f"peer{dev.removeprefix('gpu')}-")]
        sel = (device == dev).to_numpy()
        if len(mine) == 1:
            out[sel] = mine[0]
            continue
        for name in mine:
            busy = links[channels == name]
            s, e = busy["start_ns"].to_numpy(np.int64), busy["end_ns"].to_numpy(np.int64)
            if not len(s):
                continue
            k = np.clip(np.searchsorted(s, end, side="left") - 1, 0, None)  # last interval starting before
            out[sel & (s[k] < end) & (end <= e[k]) & out.isna().to_numpy()] = name
    return out


def busy_fraction(slices: pd.DataFrame, edges: np.ndarray) -> pd.DataFrame:
    """Per resource (device, track), the busy fraction of each interval between `edges`
    (ns): overlapping slices count once."""
    keys, fracs = [], []
    width = np.diff(edges).astype(float)
    for key, g in slices.groupby(["device", "track"], sort=True):
        s, e = _merge(g["start_ns"].to_numpy(np.int64), g["end_ns"].to_numpy(np.int64))
        keys.append(key)
        fracs.append((np.diff(_busy_until(s, e, edges)) / width).round(4))
    if not keys:
        return pd.DataFrame(columns=["device", "track", "ts_ns", "busy"])
    bins = len(edges) - 1  # (one table for all the resources: a frame each cost more than its rows)
    return pd.DataFrame({"device": np.repeat(np.array([k[0] for k in keys], dtype=object), bins),
                         "track": np.repeat(np.array([k[1] for k in keys], dtype=object), bins),
                         "ts_ns": np.tile(edges[:-1], len(keys)), "busy": np.concatenate(fracs)})


def _busy_until(s: np.ndarray, e: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Busy time before each of `t` on the disjoint sorted intervals [s, e)."""
    done = np.concatenate([[0], np.cumsum(e - s)])  # busy time before each interval
    k = np.searchsorted(s, t, side="right") - 1
    j = np.clip(k, 0, None)
    return np.where(k >= 0, done[j] + np.clip(t - s[j], 0, (e - s)[j]), 0)


def _merge(s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Union of intervals, sorted and disjoint."""
    if len(s) == 0:
        return s, e
    order = np.argsort(s, kind="stable")
    s, e = s[order], e[order]
    reach = np.maximum.accumulate(e)
    first = np.flatnonzero(np.concatenate([[True], s[1:] > reach[:-1]]))
    return s[first], np.maximum.reduceat(e, first)


def _counters(trace: pd.DataFrame, links: pd.DataFrame | None, pids: dict[str, int],
              slices: pd.DataFrame) -> list[list[str]]:
    """Counter events: bytes/s per channel at each change, busy fraction per track and bin."""
    out: list[list[str]] = []
    rates = link_rates(trace, links)
    if len(rates):
        device = {c: link_track(c)[0] for c in rates["channel"].unique()}
        events = pd.DataFrame({"ph": "C", "name": rates["channel"] + " bytes/s",
                               "pid": rates["channel"].map(lambda c: pids.get(device[c], 1)).astype("int64"),
                               "ts": rates["ts_ns"].to_numpy(np.int64) / 1000.0})
        out.append(_json_lines(events, pd.DataFrame({"bytes/s": rates["bytes_per_s"]})))
    if slices.empty:
        return out
    lo, hi = int(slices["start_ns"].min()), int(slices["end_ns"].max())
    bins = int(min(max(slices.loc[slices["frame"] >= 0, "frame"].nunique(), 1), 1000))
    edges = np.unique(np.linspace(lo, hi, bins + 1).round().astype(np.int64))
    if len(edges) < 2:
        return out
    busy = busy_fraction(slices, edges)
    events = pd.DataFrame({"ph": "C", "name": busy["track"] + " utilization",
                           "pid": busy["device"].map(pids).astype("int64"),
                           "ts": busy["ts_ns"].to_numpy(np.int64) / 1000.0})
    out.append(_json_lines(events, pd.DataFrame({"busy": busy["busy"]})))
    return out
