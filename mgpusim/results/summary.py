"""Results: the trace, the per-frame table and the summary, from what the engine observed.

Pure functions of data, shared by simulated and measured runs (a measured trace goes through
:func:`frames_from_trace` and :func:`summarize` just the same).
"""
from __future__ import annotations

from typing import Any, Callable, Collection, Iterable, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from mgpusim.model.errors import InputError
from mgpusim.results.periodic import RepeatedIntervals, RepeatedRows, Shift, repeated_list
from mgpusim.results.settled import settling
from mgpusim.results.trace import FRAME_COLUMNS, make_trace
from mgpusim.schedules.base import FrameProgram

#: a table, or a function that builds it on first use
LazyTable = pd.DataFrame | Callable[[], pd.DataFrame]


class Result:
    """One run: `.trace` (per task), `.frames` (per frame), `.summary` (dict), `.links`.

    The summary is computed from arrays when the run ends; `.trace`, `.frames` and `.links`
    are tables built on first read (a simulated run keeps its logs in compact form,
    :mod:`mgpusim.results.periodic`, and :meth:`trace_chunks` streams them), so a call that
    only wants the summary (a sweep point, a search) never builds a DataFrame."""

    def __init__(self, summary: dict[str, Any], trace: LazyTable, frames: LazyTable,
                 links: LazyTable | None = None, config: dict[str, Any] | None = None,
                 repeated: RepeatedRows | None = None,
                 link_logs: dict[str, RepeatedIntervals] | None = None):
        self.summary, self._frames, self.config = summary, frames, config if config is not None else {}
        self._trace, self._links = trace, links if links is not None else pd.DataFrame()
        #: the compact trace of a fast-forwarded run (None: `.trace` is the whole table)
        self.repeated = repeated
        #: the compact link logs of a fast-forwarded run, per channel (None: `.links` is whole)
        self.link_logs = link_logs
        #: seconds the model itself took (engine or recurrence), set by simulate()
        self.model_wall_s: float | None = None
        #: every frame's start and present (ns), the arrays `.frames` is built from (None: a
        #: result that was not built from arrays); a search reads them without the table
        self.frame_arrays: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def trace(self) -> pd.DataFrame:
        if callable(self._trace):
            self._trace = self._trace()
        return self._trace

    @trace.setter
    def trace(self, value: pd.DataFrame) -> None:
        self._trace = value

    @property
    def frames(self) -> pd.DataFrame:
        if callable(self._frames):
            self._frames = self._frames()
        return self._frames

    @frames.setter
    def frames(self, value: pd.DataFrame) -> None:
        self._frames = value

    @property
    def links(self) -> pd.DataFrame:
        if callable(self._links):
            self._links = self._links()
        return self._links

    @links.setter
    def links(self, value: pd.DataFrame) -> None:
        self._links = value

    @property
    def compact(self) -> bool:
        """True while the trace is kept compact (not built whole yet)."""
        return self.repeated is not None and callable(self._trace)

    def trace_chunks(self, rows_per_chunk: int = 1_000_000) -> Iterator[pd.DataFrame]:
        """The trace in sorted chunks, without building it whole when it is kept compact."""
        if self.compact:
            assert self.repeated is not None  # compact: kept as the repeated rows
            yield from self.repeated.chunks(rows_per_chunk)
            return
        trace = self.trace
        for lo in range(0, max(len(trace), 1), rows_per_chunk):
            yield trace.iloc[lo:lo + rows_per_chunk]

    def links_window(self, lo: int, hi: int) -> pd.DataFrame:
        """The link busy intervals with end > lo and start < hi, in the links table's order,
        without building a fast-forwarded run's whole table."""
        if self.link_logs is None or not callable(self._links):
            links = self.links
            return links[(links["end_ns"] > lo) & (links["start_ns"] < hi)] if len(links) else links
        return links_frame({name: log.between(lo, hi) for name, log in self.link_logs.items()})

    def links_chunks(self, before: int | None = None, rows: int = 1_000_000) -> Iterator[pd.DataFrame]:
        """The links table (only intervals starting before `before`, when given) in chunks."""
        if self.link_logs is None or not callable(self._links):
            links = self.links
            yield links if before is None or not len(links) else links[links["start_ns"] < before]
            return
        batch: list[tuple[str, np.ndarray]] = []  # channels' pieces, up to `rows` rows a chunk
        size = 0
        for name, log in self.link_logs.items():
            for piece in log.pieces(before, rows):
                if not len(piece):
                    continue
                batch.append((name, piece))
                size += len(piece)
                if size >= rows:
                    yield links_frame(batch)
                    batch, size = [], 0
        if batch:
            yield links_frame(batch)

    def trace_window(self, first: int, last: int) -> pd.DataFrame:
        """The trace rows of frames first..last-1 (sorted as the whole trace), without
        building the whole trace of a long fast-forwarded run."""
        if self.compact:
            assert self.repeated is not None  # compact: kept as the repeated rows
            return self.repeated.window(first, last)
        trace = self.trace
        return trace[(trace["frame"] >= first) & (trace["frame"] < last)].reset_index(drop=True)


def frames_table(frame_start: np.ndarray, present_end: np.ndarray) -> pd.DataFrame:
    """The per-frame table, on columns of its own (each made here, so the table shares no
    memory with the arrays; `copy=False` spares pandas copying them once more: a 10^7-frame
    table peaks at its own 305 MB, not twice that)."""
    frames = np.arange(len(present_end), dtype=np.int64)
    return pd.DataFrame({"frame": frames, "start_ns": frame_start.astype(np.int64),
                         "present_ns": present_end.astype(np.int64),
                         "latency_ns": (present_end - frame_start).astype(np.int64)},
                        columns=list(FRAME_COLUMNS), copy=False)


def frames_from_trace(trace: pd.DataFrame, present_step: str = "present") -> pd.DataFrame:
    """Per-frame start (first task start) and present (end of the present step)."""
    start = trace.groupby("frame")["start_ns"].min()
    present = trace[trace["step"] == present_step].groupby("frame")["end_ns"].max()
    df = pd.DataFrame({"start_ns": start, "present_ns": present}).dropna().astype("int64")
    df["latency_ns"] = df["present_ns"] - df["start_ns"]
    return df.reset_index().rename(columns={"index": "frame"})[list(FRAME_COLUMNS)]


def summarize(frames: pd.DataFrame, trace: pd.DataFrame | None, warmup_frames: int,
              links: pd.DataFrame | None = None,
              busy: Callable[[int, int], dict[str, int]] | None = None,
              leave_out: Collection[int] = ()) -> dict[str, Any]:
    """:func:`summarize_arrays` of a frames table. Utilization comes from `busy(lo, hi)`
    (busy ns per resource in the window) when given, else from the trace and links tables."""
    if busy is None and trace is not None and len(trace):
        def busy(lo: int, hi: int) -> dict[str, int]:
            return table_busy(trace, links, lo, hi)
    return summarize_arrays(frames["frame"].to_numpy(np.int64), frames["start_ns"].to_numpy(np.int64),
                            frames["present_ns"].to_numpy(np.int64), warmup_frames, busy, leave_out)


def summarize_arrays(frame: np.ndarray | None, start: np.ndarray, present: np.ndarray, warmup_frames: int,
                     busy: Callable[[int, int], dict[str, int]] | None = None,
                     leave_out: Collection[int] = ()) -> dict[str, Any]:
    """Steady-state figures after `warmup_frames`, from per-frame arrays (frame number, first
    start, present; frame None: frames 0, 1, ... in order, a simulated run's, with no array
    of them): frame time = mean period between presents. With a single steady frame its
    period is measured from the last warm-up frame's present (or, with no warm-up, from its
    own start). Utilization: `busy(lo, hi)` over the window, when given. `leave_out`: frames
    whose period and latency the figures skip (a measured run's stalls). Arrays, no tables:
    a run's summary costs microseconds."""
    if frame is None:
        frame = np.arange(len(present), dtype=np.int64) if leave_out else None
    if frame is None:  # (a view, not a copy: 80 MB each at 10^7 frames)
        steady: np.ndarray | slice = slice(warmup_frames, None)
        if warmup_frames >= len(present):
            raise InputError(f"no frame presents after the {warmup_frames} warm-up frames "
                             f"(the run has {len(present)})", field="schedule.warmup_frames")
    else:
        steady = frame >= warmup_frames
        if not steady.any():
            raise InputError(f"no frame presents after the {warmup_frames} warm-up frames "
                             f"(the run has {len(frame)})", field="schedule.warmup_frames")
    presents = present[steady].astype(np.int64, copy=False)
    latency = present[steady] - start[steady]
    if len(presents) == 1:
        before = present[:warmup_frames] if frame is None else present[frame < warmup_frames]
        origin = int(before[-1]) if len(before) else int(start[steady][0])
        presents = np.array([origin, presents[0]], dtype=np.int64)
    periods = np.diff(presents)
    window = (int(presents[0]), int(presents[-1]))
    if leave_out:
        assert frame is not None  # (made above where frames are to be left out)
        out_of = np.isin(frame[steady], list(leave_out))
        periods = periods[~out_of[1:]]
        latency = latency[~out_of]
    latency_ns = float(latency.mean())
    del presents, latency  # (each 80 MB in a 10^7-frame run: gone before the jitter's temporary)
    frame_time = float(periods.mean())
    out: dict[str, Any] = {
        "frame_time_ms": frame_time / 1e6,
        "fps": 1e9 / frame_time if frame_time > 0 else float("inf"),
        "latency_ms": latency_ns / 1e6,
        "frame_time_jitter_ms": float(periods.std()) / 1e6,
        "frame_time_min_ms": float(periods.min()) / 1e6,
        "frame_time_max_ms": float(periods.max()) / 1e6,
        "frames": int(len(present)),
        "warmup_frames": int(warmup_frames),
        "window_ns": list(window),
    }
    if busy is not None:
        span = max(window[1] - window[0], 1)
        out["utilization"] = {name: round(b / span, 6) for name, b in sorted(busy(*window).items())}
    return out


def utilization(trace: pd.DataFrame, links: pd.DataFrame | None, window: tuple[int, int]) -> dict[str, float]:
    """Busy fraction of every queue, host thread and link over the steady-state window."""
    lo, hi = window
    span = max(hi - lo, 1)
    return {name: round(b / span, 6) for name, b in sorted(table_busy(trace, links, lo, hi).items())}


def table_busy(trace: pd.DataFrame, links: pd.DataFrame | None, lo: int, hi: int) -> dict[str, int]:
    """Busy ns of every queue and host thread (`device.engine`) and link inside [lo, hi]."""
    busy = _busy(trace.assign(resource=trace["device"].astype(str) + "." + trace["engine"].astype(str)), lo, hi)
    if links is not None and len(links):
        busy.update(_busy(links.rename(columns={"channel": "resource"}), lo, hi))
    return busy


def _busy(df: pd.DataFrame, lo: int, hi: int) -> dict[str, int]:
    s = df["start_ns"].clip(lo, hi).to_numpy()
    e = df["end_ns"].clip(lo, hi).to_numpy()
    d = pd.DataFrame({"resource": df["resource"].to_numpy(), "dur": e - s})
    return {str(k): int(v) for k, v in d.groupby("resource")["dur"].sum().items()}


def link_track(channel: str) -> tuple[str, str]:
    """(device, track) on which a channel's busy intervals are drawn: `gpu1.d2h` ->
    ("gpu1", "link d2h"), `peer0-1` -> ("gpu0", "link peer0-1"), `host.memory` -> ("host", "memory"),
    a shared GPU's execution `gpu0.exec` -> ("gpu0", "exec")."""
    if channel.endswith(".exec"):
        return channel.partition(".")[0], "exec"
    if channel.startswith("host."):
        return "host", channel.partition(".")[2]
    if channel.startswith("peer"):
        return "gpu" + channel[4:].split("-")[0], f"link {channel}"
    device, _, path = channel.partition(".")
    return device, f"link {path}"


LINK_DTYPES = {"channel": "string", "start_ns": "int64", "end_ns": "int64"}
_NO_LINKS = pd.DataFrame([], columns=list(LINK_DTYPES)).astype(LINK_DTYPES)


def links_frame(arrays: Mapping[str, np.ndarray] | Iterable[tuple[str, np.ndarray]]) -> pd.DataFrame:
    """A links table from (start, end) arrays per channel (a mapping or (channel, array)
    pairs), channel after channel. Built on the arrays joined, one frame for all the channels:
    a frame per channel cost more than its rows (a fast-forwarded run's links file has one
    chunk of channels, not a row group per channel)."""
    pairs = list(arrays.items() if isinstance(arrays, Mapping) else arrays)
    if not pairs:
        return _NO_LINKS.copy()
    both = np.concatenate([a for _, a in pairs]) if len(pairs) > 1 else pairs[0][1]
    channel = np.repeat(np.array([name for name, _ in pairs], dtype=object), [len(a) for _, a in pairs])
    return pd.DataFrame({"channel": channel, "start_ns": both[:, 0], "end_ns": both[:, 1]}).astype(LINK_DTYPES)


def _labels(raw) -> Callable[[], Sequence[str]] | None:
    """The `waits_for` text of each task id the rows log, built when called (None: the rows
    log the text itself)."""
    inputs = getattr(raw, "inputs", None)
    return None if inputs is None else (lambda: inputs.labels)


def _frame_logs(raw) -> tuple[Shift, RepeatedRows, np.ndarray, np.ndarray]:
    """(the repeat's shift, the compact rows, every frame's start and present) of a run."""
    r = raw.repeat
    shift = Shift(r.frames, r.ns, r.copies) if r is not None else Shift(1, 0, 0)
    rows = RepeatedRows(raw.rows, r.rows if r is not None else (len(raw.rows),) * 2, shift, _labels(raw))
    if r is not None and not raw.frames_whole:
        start, present = rows.frame_arrays(len(raw.frame_start), raw.present_task)
    else:
        start, present = raw.frame_start, raw.present_end
    return shift, rows, start, present


def frame_figures(raw, warmup_frames: int) -> dict[str, Any]:
    """:func:`summarize_arrays` of a run's frames alone: what its Result's summary says of
    the frame time and latency, without utilization, settling, skips or tables. Why: a band's
    ends (`simulate(band=True)`) read two figures; a 10^7-frame run's whole Result would hold
    its skipped-frame lists and more beside the main run's."""
    _shift, _rows, start, present = _frame_logs(raw)
    return summarize_arrays(None, start, present, warmup_frames)


def build_result(raw, warmup_frames: int, config: dict[str, Any]) -> Result:
    """A run's Result from what the engine (or the analytic level) observed: the summary from
    arrays at once; the trace, frames and links tables built only when read. A fast-forwarded
    run's logs are kept compact (:mod:`mgpusim.results.periodic`); a run without a repeat is
    the same form with nothing repeated. `settled` and `settling`: whether the run's frame time
    and latency had settled by its end (:mod:`mgpusim.results.settled`)."""
    r = raw.repeat
    shift, rows, start, present = _frame_logs(raw)
    links = {name: RepeatedIntervals(ch.busy, r.busy.get(name, (len(ch.busy),) * 2) if r is not None
                                     else (len(ch.busy),) * 2, shift,
                                     r.held_open.get(name) if r is not None else None)
             for name, ch in raw.channels.items()}

    def busy(lo: int, hi: int) -> dict[str, int]:
        out = rows.busy(lo, hi)
        out.update({name: log.busy(lo, hi) for name, log in links.items() if len(log)})
        return out

    def whole_links() -> pd.DataFrame:
        return links_frame({name: log.array() for name, log in links.items()})

    def frames() -> pd.DataFrame:
        return frames_table(start, present)

    summary = summarize_arrays(None, start, present, warmup_frames,
                               busy=busy if len(rows) and raw.recorded else None)
    summary["settled"] = False
    summary["settling"] = settling(start, present, warmup_frames)  # mgpusim/results/settled.py
    summary["settled"] = bool(summary["settling"]["frame_time_settled"] and summary["settling"]["latency_settled"])
    summary["effects"] = raw.effects
    if raw.skipped:
        if r is not None:  # a task first skipped after the repeat was found has all its skips in the rest
            raw.skipped_frames = {name: repeated_list(f, r.skipped.get(name, (0, 0)), shift)
                                  for name, f in raw.skipped_frames.items()}
            summary["skipped_tasks"] = {name: len(f) for name, f in raw.skipped_frames.items()}
        else:
            summary["skipped_tasks"] = raw.skipped
    if not raw.recorded:
        result = Result(summary, lambda: make_trace([]), frames, whole_links, config, link_logs=links)
    else:
        result = Result(summary, rows.frame, frames, whole_links, config, repeated=rows, link_logs=links)
    result.frame_arrays = (start, present)
    return result


def task_rates(program: FrameProgram, skipped_frames: Mapping[str, Sequence[int]],
               summary: Mapping[str, Any]) -> dict[str, float] | None:
    """Steady-state completion rate (Hz) of each skippable task (e.g. particle updates under
    "new wait") beside the frame rate: runs in frames after warm-up over the summary's present
    window. The same rule for simulated and measured runs; None if the program has none."""
    if not program.rate_tasks:
        return None
    lo, hi = summary["window_ns"]
    first = program.warmup_frames + 1
    frames = program.frames - first
    rates = {}
    for name in program.rate_tasks:
        skipped = sum(1 for f in skipped_frames.get(name, ()) if f >= first)
        rates[name] = (frames - skipped) * 1e9 / (hi - lo) if hi > lo else 0.0
    rates["frames"] = summary["fps"]
    return rates
