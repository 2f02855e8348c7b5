"""A fast-forwarded run's logs, as the full run's: a prefix, a block repeated, and the rest.

The engine's fast-forward (:mod:`mgpusim.sim.fastforward`) ran a shorter run that passes through
the same states; the full run logged the shorter run's prefix, then its repeated block once per
step (each shifted by `frames` frames and `ns` ns), then the shorter run's rest shifted by all
the skipped steps, in that order. Everything here works on that compact form, so tables,
per-frame figures and busy times of a 10^6-frame run cost what the shorter run cost; the full
trace is built only when asked for, or streamed in chunks sorted as :func:`trace.make_trace`
sorts (by start, end, device, engine; ties in logging order).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import pandas as pd

from mgpusim.results.trace import TRACE_COLUMNS, TRACE_DTYPES, waits_for_categories

_INT = ("frame", "start_ns", "end_ns", "bytes")
#: text columns kept as codes into one sorted dictionary each (code order is string order)
_STR = ("device", "engine", "step", "task")
#: the inputs column: task ids, whose labels are built only when a table is
_WAITS = "waits_for"


@dataclass(frozen=True)
class Shift:
    """Step `frames` frames and `ns` ns, `copies` + 1 times for the block; the rest moves by
    `copies` steps."""

    frames: int
    ns: int
    copies: int


def _shifted(cols: dict[str, np.ndarray], frames: int, ns: int) -> dict[str, np.ndarray]:
    out = dict(cols)
    for name, by in (("frame", frames), ("start_ns", ns), ("end_ns", ns)):
        if name in cols:
            out[name] = cols[name] + by
    return out


def _encode(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes, sorted distinct strings) of an object array of strings: hashed, not sorted
    row by row, so a long log of a few names costs one pass."""
    codes, uniques = pd.factorize(values)
    names = np.asarray(uniques, dtype=object).astype(str)
    order = np.argsort(names, kind="stable")
    rank = np.empty(len(order), dtype=np.int32)
    rank[order] = np.arange(len(order), dtype=np.int32)
    return rank[codes], names[order]


class RowColumns:
    """Trace rows held as columns (each a sequence in TRACE_COLUMNS' order of names; the
    number columns int64 arrays): the log of a run that filled frames in by arithmetic
    (:mod:`mgpusim.sim.affine`), which needs no tuple per row. :class:`RepeatedRows` takes it
    where it takes a list of rows."""

    __slots__ = ("columns", "queues")

    def __init__(self, columns: dict[str, Sequence[Any]], queues: tuple[np.ndarray, list[str]] | None = None):
        """`queues`: what :attr:`RepeatedRows._queues` would find (each row's queue code,
        the names), where the caller has it from the rows' pattern."""
        self.columns, self.queues = columns, queues

    def __len__(self) -> int:
        return len(self.columns["frame"])


class RepeatedRows:
    """The trace rows of a fast-forwarded run (see the module doc); a run without a repeat is
    the same with an empty block. What the summary reads (per-frame starts and presents, busy
    time per queue) comes from the numbers and one code per queue; the text columns are coded
    only when a table is built: into one sorted dictionary per column (code order is string
    order), `waits_for` as the task ids the engine logged, with `labels()` giving each id's
    text (None: the rows carry the text, which is then coded like the others)."""

    def __init__(self, rows: list[tuple] | RowColumns, split: tuple[int, int], shift: Shift,
                 labels: Callable[[], Sequence[str]] | None = None):
        self._rows, self._split, self.shift, self._given_labels = rows, split, shift, labels
        if isinstance(rows, RowColumns):
            self._text: dict[str, Sequence[Any]] = dict(rows.columns)
        else:
            self._text = dict(zip(TRACE_COLUMNS, list(zip(*rows)) if rows else [()] * len(TRACE_COLUMNS)))
        self._numbers = {c: np.asarray(self._text[c], dtype=np.int64) for c in _INT}

    def _parts(self, cols: dict[str, np.ndarray]) -> tuple[dict, dict, dict]:
        """Prefix, block and rest (shifted by the skipped steps) of whole-log columns."""
        a, b = self._split
        prefix = {c: v[:a] for c, v in cols.items()}
        block = {c: v[a:b] for c, v in cols.items()}
        rest = _shifted({c: v[b:] for c, v in cols.items()}, self.shift.copies * self.shift.frames,
                        self.shift.copies * self.shift.ns)
        return prefix, block, rest

    @functools.cached_property
    def _coded(self) -> tuple[tuple[dict, dict, dict], dict[str, np.ndarray],
                              Callable[[], Sequence[str] | np.ndarray]]:
        """The parts with every column as numbers, the dictionaries, the labels of `waits_for`."""
        cols = dict(self._numbers)
        dictionary: dict[str, np.ndarray] = {}
        for c in _STR:
            cols[c], dictionary[c] = _encode(np.array(self._text[c], dtype=object))
        labels: Callable[[], Sequence[str] | np.ndarray]
        if self._given_labels is not None:
            cols[_WAITS] = np.array(self._text[_WAITS], dtype=np.int64)
            labels = self._given_labels
        else:
            cols[_WAITS], names = _encode(np.array(self._text[_WAITS], dtype=object))
            labels = lambda: names  # noqa: E731
        return self._parts(cols), dictionary, labels

    @property
    def prefix(self) -> dict[str, np.ndarray]:
        return self._coded[0][0]

    @property
    def block(self) -> dict[str, np.ndarray]:
        return self._coded[0][1]

    @property
    def rest(self) -> dict[str, np.ndarray]:
        return self._coded[0][2]

    @property
    def dictionary(self) -> dict[str, np.ndarray]:
        return self._coded[1]

    @functools.cached_property
    def waits_for(self) -> tuple[np.ndarray, Any]:
        """(category code of each task id, the distinct `waits_for` labels)."""
        return waits_for_categories(self._coded[2]())

    def __len__(self) -> int:
        a, b = self._split
        return len(self._rows) + self.shift.copies * (b - a)

    # ----- per frame ---------------------------------------------------------------------
    def frame_arrays(self, frames: int, present_task: str) -> tuple[np.ndarray, np.ndarray]:
        """(first task start, present end) per frame, as the engine records them (a frame's
        present is its present task's end on a GPU queue)."""
        is_present = np.array([t == present_task and d != "host" for t, d in
                               zip(self._text["task"], self._text["device"])], dtype=bool)
        prefix, b, rest = self._parts({**self._numbers, "present": is_present})
        start = np.full(frames, np.iinfo(np.int64).max, dtype=np.int64)
        present = np.full(frames, -1, dtype=np.int64)
        for part in (prefix, rest):
            np.minimum.at(start, part["frame"], part["start_ns"])
            mask = part["present"]
            np.maximum.at(present, part["frame"][mask], part["end_ns"][mask])
        p, copies = self.shift.frames, self.shift.copies
        for frame in np.unique(b["frame"]).tolist():
            in_frame = b["frame"] == frame
            steps = slice(frame, frame + p * copies + 1, p)  # the frame in each copy of the block
            _stepped(np.minimum, start[steps], int(b["start_ns"][in_frame].min()), self.shift.ns)
            ends = b["end_ns"][in_frame & b["present"]]
            if len(ends):
                _stepped(np.maximum, present[steps], int(ends.max()), self.shift.ns)
        return start, present

    def rows_per_frame(self, frames: int) -> np.ndarray:
        """How many rows each of frames 0..frames-1 has (the block's counts added per copy)."""
        prefix, block, rest = self._parts({"frame": self._numbers["frame"]})
        counts = np.zeros(frames, dtype=np.int64)
        for part in (prefix, rest):
            np.add.at(counts, part["frame"], 1)
        step, copies = self.shift.frames, self.shift.copies
        for frame, count in zip(*np.unique(block["frame"], return_counts=True)):
            counts[int(frame):int(frame) + (copies + 1) * step:step] += int(count)
        return counts

    # ----- busy time ---------------------------------------------------------------------
    @functools.cached_property
    def _queues(self) -> tuple[np.ndarray, list[str]]:
        """(code per row, names): each row's queue or host thread, `device.engine`, coded in
        order of first appearance. (A dictionary pass: a run's log names a few dozen queues,
        and hashing pairs of the same few strings costs less than sorting codes in numpy.)"""
        if isinstance(self._rows, RowColumns) and self._rows.queues is not None:
            return self._rows.queues
        pairs = list(zip(self._text["device"], self._text["engine"]))
        index = {k: i for i, k in enumerate(dict.fromkeys(pairs))}
        codes = np.array(list(map(index.__getitem__, pairs)), dtype=np.int64)
        return codes, [f"{device}.{engine}" for device, engine in index]

    def busy(self, lo: int, hi: int) -> dict[str, int]:
        """Busy ns of every queue and host thread (`device.engine`) inside [lo, hi]."""
        codes, names = self._queues
        a, b = self._split
        start, end = self._numbers["start_ns"], self._numbers["end_ns"]
        total = np.zeros(len(names), dtype=np.int64)
        moved = self.shift.copies * self.shift.ns  # the rest's shift
        for sl, by in ((slice(0, a), 0), (slice(b, None), moved)):
            s, e = start[sl], end[sl]
            if len(s):
                dur = np.clip(e, lo - by, hi - by) - np.clip(s, lo - by, hi - by)
                np.add.at(total, codes[sl], dur)
        if b > a:
            np.add.at(total, codes[a:b], shifted_overlaps(start[a:b], end[a:b], self.shift.ns,
                                                          self.shift.copies, lo, hi))
        return {name: int(v) for name, v in zip(names, total.tolist())}

    # ----- the trace ---------------------------------------------------------------------
    def chunks(self, rows_per_chunk: int = 1_000_000, frames: int | None = None) -> Iterator[pd.DataFrame]:
        """The whole trace (or its rows of frames below `frames`), sorted as make_trace sorts
        it, in chunks of about `rows_per_chunk` rows (by start time: every row of one start
        time is in one chunk)."""
        for cols in self._sorted_chunks(rows_per_chunk, frames):
            yield self._frame(cols)

    def arrow_chunks(self, schema: Any, rows_per_chunk: int = 1_000_000,
                     frames: int | None = None) -> Iterator[Any]:
        """The same chunks as pyarrow Tables of `schema` (strings built in Arrow, not Python;
        a dictionary-typed field gets the codes and dictionary as they are)."""
        import pyarrow as pa  # noqa: PLC0415 (only the streaming writer needs it)
        codes, uniques = self.waits_for
        dicts = {c: pa.array(self.dictionary[c].tolist(), type=pa.large_string()) for c in _STR}
        dicts[_WAITS] = pa.array(list(uniques), type=pa.large_string())
        for cols in self._sorted_chunks(rows_per_chunk, frames):
            arrays = []
            for field in schema:
                if field.name in dicts:
                    values = codes[cols[_WAITS]] if field.name == _WAITS else cols[field.name]
                    array = pa.DictionaryArray.from_arrays(pa.array(values.astype(np.int32)), dicts[field.name])
                    arrays.append(array if array.type == field.type else array.cast(field.type))
                else:
                    arrays.append(pa.array(cols[field.name], type=field.type))
            yield pa.Table.from_arrays(arrays, schema=schema)

    def window(self, first: int, last: int) -> pd.DataFrame:
        """The rows of frames first..last-1 only, sorted as the whole trace is."""
        parts = [_frames_in(self.prefix, first, last)]
        b = self.block
        if len(b["frame"]) and self.shift.frames:
            p = self.shift.frames
            j0 = max(0, -((int(b["frame"].max()) - first) // p))
            j1 = min(self.shift.copies, (last - 1 - int(b["frame"].min())) // p)
            for j in range(j0, j1 + 1):
                parts.append(_frames_in(_shifted(b, j * p, j * self.shift.ns), first, last))
        parts.append(_frames_in(self.rest, first, last))
        return self._frame(_sort({c: np.concatenate([x[c] for x in parts]) for c in TRACE_COLUMNS}))

    def _sorted_chunks(self, rows_per_chunk: int, frames: int | None = None) -> Iterator[dict[str, np.ndarray]]:
        """The rows (of frames below `frames`, when given) in sorted chunks of about
        `rows_per_chunk` rows, each chunk the rows that start in one span of time. Where the
        block's copies alone fill a span (the steady middle of the run), every period of it
        holds the same rows in the same order, shifted: those spans are tiled from one sorted
        period (:class:`_SteadyOrder`), not sorted again."""
        starts = [p["start_ns"] for p in (self.prefix, self.block, self.rest) if len(p["start_ns"])]
        if not starts:
            yield {c: self.prefix[c] for c in TRACE_COLUMNS}
            return
        lo = min(int(s.min()) for s in starts)
        hi = max(int(s.max()) for s in starts) + self.shift.copies * self.shift.ns + 1
        if frames is not None:
            hi = min(hi, self._last_start(frames) + 1)
        per_step = max(1, len(self.block["frame"]))
        steps = max(1, rows_per_chunk // per_step)
        width = steps * self.shift.ns if self.shift.ns else hi - lo
        steady = _SteadyOrder.of(self)
        a = lo
        while a < hi:
            if steady is not None and steady.first <= a < steady.end:
                b = min(steady.end, a + width)  # whole periods (past hi: the frame filter drops them)
                cols = steady.rows(a, b)
            else:
                b = min(hi, a + width, steady.first if steady is not None and a < steady.first else hi)
                cols = self._between(a, b)
            if frames is not None:
                keep = cols["frame"] < frames
                cols = {c: v[keep] for c, v in cols.items()}
            yield cols
            a = b

    def _last_start(self, frames: int) -> int:
        """A bound on the start of any row of a frame below `frames`."""
        out = -1
        for part in (self.prefix, self.rest):
            mask = part["frame"] < frames
            if mask.any():
                out = max(out, int(part["start_ns"][mask].max()))
        b = self.block
        if len(b["frame"]):
            copies = min(self.shift.copies, max(0, (frames - int(b["frame"].min())) // max(self.shift.frames, 1)))
            out = max(out, int(b["start_ns"].max()) + copies * self.shift.ns)
        return out

    def frame(self) -> pd.DataFrame:
        """The whole trace as one DataFrame (what make_trace would build from every row)."""
        return pd.concat(list(self.chunks(rows_per_chunk=len(self) + 1)), ignore_index=True)

    def _between(self, a: int, b: int) -> dict[str, np.ndarray]:
        """Rows starting in [a, b), sorted."""
        parts = [_take(self.prefix, a, b)]
        blk = self.block
        if len(blk["frame"]):
            t = self.shift.ns
            if t:
                j0 = max(0, -((int(blk["start_ns"].max()) - a) // t))  # ceil((a - max) / t)
                j1 = min(self.shift.copies, (b - 1 - int(blk["start_ns"].min())) // t)
            else:
                j0, j1 = 0, self.shift.copies
            if j1 >= j0:
                parts.append(_tiled(blk, j0, j1, self.shift, a, b))
        parts.append(_take(self.rest, a, b))
        return _sort({c: np.concatenate([p[c] for p in parts]) for c in TRACE_COLUMNS})

    def _frame(self, cols: dict[str, np.ndarray]) -> pd.DataFrame:
        """A DataFrame with make_trace's dtypes; strings are built in Arrow from the codes
        (no Python string per row), `waits_for` as a categorical of the task ids' labels."""
        import pyarrow as pa  # noqa: PLC0415
        data: dict[str, Any] = {}
        for c in TRACE_COLUMNS:
            if c in _STR:
                codes = pa.array(cols[c].astype(np.int32), type=pa.int32())
                strings = pa.DictionaryArray.from_arrays(codes, pa.array(self.dictionary[c].tolist(),
                                                                         type=pa.string()))
                data[c] = pd.array(strings.cast(pa.large_string()), dtype=TRACE_DTYPES[c])
            elif c == _WAITS:
                codes, uniques = self.waits_for
                data[c] = pd.Categorical.from_codes(codes[cols[c]], categories=uniques)
            else:
                data[c] = cols[c].astype(TRACE_DTYPES[c])
        return pd.DataFrame(data, columns=list(TRACE_COLUMNS))


class _SteadyOrder:
    """The steady middle of a fast-forwarded trace, sorted once and tiled.

    Cut time into periods [first + k T, first + (k + 1) T). A block row starting at s lies,
    in copy j, in period k = j + d with d = (s - first) // T: so every period k with all of
    its rows' copies in range (d_max <= k <= copies) and no prefix or rest row starting in
    it holds exactly one copy of every block row (copy k - d), in the same order: by start,
    end, device, engine, then logging order (earlier copy, then row). That order is found
    once; a span of such periods is the block in that order, tiled, shifted by k."""

    def __init__(self, rows: RepeatedRows, first: int, k_first: int, k_last: int):
        b, t = rows.block, rows.shift.ns
        d = (b["start_ns"] - first) // t
        order = np.lexsort((np.arange(len(d)), -d, b["engine"], b["device"], b["end_ns"] - d * t,
                            b["start_ns"] - d * t))
        self.base = {c: v[order] for c, v in b.items()}
        self.copy = -d[order]  # copy index minus k, per sorted row
        self.shift, self.origin = rows.shift, first
        self.k_first = k_first
        self.first, self.end = first + k_first * t, first + (k_last + 1) * t

    @classmethod
    def of(cls, rows: RepeatedRows) -> "_SteadyOrder | None":
        """The steady span of `rows`, or None where there is none (no block, no time shift,
        or a prefix and rest that leave no whole period to the block alone)."""
        b, t = rows.block, rows.shift.ns
        if not len(b["frame"]) or t <= 0:
            return None
        first = int(b["start_ns"].min())
        k_first = int((b["start_ns"].max() - first) // t)
        if len(rows.prefix["start_ns"]):
            k_first = max(k_first, (int(rows.prefix["start_ns"].max()) - first) // t + 1)
        k_last = rows.shift.copies
        if len(rows.rest["start_ns"]):
            k_last = min(k_last, (int(rows.rest["start_ns"].min()) - first) // t - 1)
        return cls(rows, first, k_first, k_last) if k_first <= k_last else None

    def rows(self, a: int, b: int) -> dict[str, np.ndarray]:
        """The sorted rows starting in [a, b), both on period edges inside the span."""
        t = self.shift.ns
        k0, k1 = (a - self.origin) // t, (b - self.origin) // t
        n = len(self.copy)
        j = np.repeat(np.arange(k0, k1, dtype=np.int64), n) + np.tile(self.copy, k1 - k0)
        out = {c: np.tile(v, k1 - k0) for c, v in self.base.items()}
        out["frame"] += j * self.shift.frames
        out["start_ns"] += j * t
        out["end_ns"] += j * t
        return out


def _stepped(pick: np.ufunc, values: np.ndarray, first: int, ns: int, chunk: int = 1 << 16) -> None:
    """values[j] = pick(values[j], first + j ns) for every j, in place, a chunk at a time (a
    10^7-copy block's steps, shifts and picks would be 80 MB arrays each)."""
    assert values.base is not None  # (a view into the frame arrays: written through)
    for lo in range(0, len(values), chunk):
        part = values[lo:lo + chunk]
        pick(part, first + ns * np.arange(lo, lo + len(part), dtype=np.int64), out=part)


def _tiled(block: dict[str, np.ndarray], j0: int, j1: int, shift: Shift, a: int, b: int) -> dict[str, np.ndarray]:
    """Copies j0..j1 of the block, in order, keeping rows that start in [a, b)."""
    n = j1 - j0 + 1
    steps = np.repeat(np.arange(j0, j1 + 1, dtype=np.int64), len(block["frame"]))
    out = {c: np.tile(v, n) for c, v in block.items()}
    out["frame"] = out["frame"] + steps * shift.frames
    out["start_ns"] = out["start_ns"] + steps * shift.ns
    out["end_ns"] = out["end_ns"] + steps * shift.ns
    return _take(out, a, b)


def _frames_in(part: dict[str, np.ndarray], first: int, last: int) -> dict[str, np.ndarray]:
    mask = (part["frame"] >= first) & (part["frame"] < last)
    return {c: v[mask] for c, v in part.items()}


def _sort(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """make_trace's order: start, end, device, engine; ties in logging order (stable)."""
    if not len(cols["frame"]):
        return cols
    order = np.lexsort((cols["engine"], cols["device"], cols["end_ns"], cols["start_ns"]))
    return {c: v[order] for c, v in cols.items()}


def shifted_overlap(s: int, e: int, t: int, copies: int, lo: int, hi: int) -> int:
    """Sum over j = 0..copies of the overlap of [s + j t, e + j t] with [lo, hi] (exact)."""
    def overlap(j: int) -> int:
        return max(0, min(e + j * t, hi) - max(s + j * t, lo))
    if t == 0:
        return (copies + 1) * overlap(0)
    first = max(0, (lo - e) // t + 1)          # first j whose interval ends after lo
    last = min(copies, -((s - hi) // t) - 1)   # last j whose interval starts before hi
    if first > last:
        return 0
    inside_lo = max(first, -((s - lo) // t) if s < lo else 0)  # s + j t >= lo
    inside_hi = min(last, (hi - e) // t)                       # e + j t <= hi
    total = 0
    if inside_lo <= inside_hi:
        total += (inside_hi - inside_lo + 1) * (e - s)
        edges = list(range(first, inside_lo)) + list(range(inside_hi + 1, last + 1))
    else:
        edges = list(range(first, last + 1))
    return total + sum(overlap(j) for j in edges)


def shifted_overlaps(s: np.ndarray, e: np.ndarray, t: int, copies: int, lo: int, hi: int) -> np.ndarray:
    """:func:`shifted_overlap` of every interval [s[i], e[i]] at once (int64, exact). Over
    the copies j that reach the window, each overlap is e - s (inside), e + jt - lo (across lo),
    hi - s - jt (across hi) or hi - lo (over it): arithmetic series summed in closed form. Where
    an interval is longer than the step (no log of one queue or thread has such), the step is
    0 or the intervals are few, each interval is summed one by one, in Python integers."""
    if len(s) < 32 or t <= 0 or int((e - s).max()) > t:  # (a short block: Python costs less)
        return np.array([shifted_overlap(a, b, t, copies, lo, hi) for a, b in zip(s.tolist(), e.tolist())],
                        dtype=np.int64)

    def count(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.maximum(0, b - a + 1)
    first = np.maximum(0, (lo - e) // t + 1)      # first j whose interval ends after lo
    last = np.minimum(copies, -((s - hi) // t) - 1)  # last j whose interval starts before hi
    starts_in = -((s - lo) // t)                  # first j with s + jt >= lo
    ends_in = (hi - e) // t                       # last j with e + jt <= hi
    inside = count(np.maximum(first, starts_in), np.minimum(last, ends_in))
    n_lo = count(first, np.minimum(np.minimum(last, ends_in), starts_in - 1))
    across_lo = n_lo * (e - lo + first * t) + t * (n_lo * (n_lo - 1) // 2)
    hi_from = np.maximum(np.maximum(first, starts_in), ends_in + 1)
    n_hi = count(hi_from, last)
    across_hi = n_hi * (hi - s - hi_from * t) - t * (n_hi * (n_hi - 1) // 2)
    over = count(np.maximum(first, ends_in + 1), np.minimum(last, starts_in - 1))
    return inside * (e - s) + across_lo + across_hi + over * (hi - lo)


def _take(part: dict[str, np.ndarray], a: int, b: int) -> dict[str, np.ndarray]:
    mask = (part["start_ns"] >= a) & (part["start_ns"] < b)
    return {c: v[mask] for c, v in part.items()}


class RepeatedIntervals:
    """One log of (start, end) intervals (a channel's busy times) of a fast-forwarded run."""

    def __init__(self, intervals: list[tuple[int, int]], split: tuple[int, int], shift: Shift,
                 held_open_since: int | None = None):
        """`held_open_since`: the log's interval was open over the whole block; it began then
        (its start does not move with the repeats, its end does)."""
        arr = np.array(intervals, dtype=np.int64).reshape(-1, 2)
        self.prefix, self.block = arr[:split[0]], arr[split[0]:split[1]]
        self.rest = arr[split[1]:] + shift.copies * shift.ns
        if held_open_since is not None and len(self.rest):
            self.rest[0, 0] = held_open_since
        self.shift = shift

    def __len__(self) -> int:
        return len(self.prefix) + (self.shift.copies + 1) * len(self.block) + len(self.rest)

    def array(self) -> np.ndarray:
        return np.concatenate(list(self.array_chunks(len(self) + 1)) or [self.prefix])

    def array_chunks(self, rows_per_chunk: int = 1_000_000) -> Iterator[np.ndarray]:
        """The log in order (prefix, each step of the block, rest), about `rows_per_chunk`
        intervals at a time: a 10^6-frame run's links never held whole."""
        yield self.prefix
        if len(self.block):
            per = max(1, rows_per_chunk // len(self.block))
            for j in range(0, self.shift.copies + 1, per):
                steps = self.shift.ns * np.arange(j, min(j + per, self.shift.copies + 1), dtype=np.int64)
                yield (self.block[None, :, :] + steps[:, None, None]).reshape(-1, 2)
        yield self.rest

    def overlapping(self, lo: int, hi: int) -> np.ndarray:
        """The intervals (in log order) with end > lo and start < hi, from the steps of the
        block that can reach [lo, hi) only."""
        parts = [_overlap(self.prefix, lo, hi)]
        if len(self.block):
            ns, copies = self.shift.ns, self.shift.copies
            if ns > 0:
                j0 = max(0, (lo - int(self.block[:, 1].max())) // ns)
                j1 = min(copies, (hi - int(self.block[:, 0].min())) // ns + 1)
            else:
                j0, j1 = 0, min(copies, 0)
            if j0 <= j1:
                steps = ns * np.arange(j0, j1 + 1, dtype=np.int64)
                parts.append(_overlap((self.block[None, :, :] + steps[:, None, None]).reshape(-1, 2), lo, hi))
        parts.append(_overlap(self.rest, lo, hi))
        return np.concatenate(parts)

    def _copies(self, lo: int | None, hi: int | None) -> tuple[int, int]:
        """A range of block copies j0..j1 that holds every copy with an interval overlapping
        (lo, hi) (None: unbounded); exact filtering is the caller's."""
        t, copies = self.shift.ns, self.shift.copies
        if not len(self.block) or t <= 0:
            return 0, copies
        j0 = 0 if lo is None else max(0, (lo - int(self.block[:, 1].max())) // t)
        j1 = copies if hi is None else min(copies, (hi - int(self.block[:, 0].min())) // t + 1)
        return j0, j1

    def _tiled(self, j0: int, j1: int) -> np.ndarray:
        steps = self.shift.ns * np.arange(j0, j1 + 1, dtype=np.int64)
        return (self.block[None, :, :] + steps[:, None, None]).reshape(-1, 2)

    def between(self, lo: int, hi: int) -> np.ndarray:
        """The intervals with end > lo and start < hi, in log order (what filtering
        :meth:`array` would keep), tiling only the copies that can overlap."""
        j0, j1 = self._copies(lo, hi)
        parts = [self.prefix, self._tiled(j0, j1) if j1 >= j0 else self.block[:0], self.rest]
        arr = np.concatenate(parts)
        return arr[(arr[:, 1] > lo) & (arr[:, 0] < hi)]

    def pieces(self, before: int | None = None, rows: int = 1_000_000) -> Iterator[np.ndarray]:
        """The log in order (only intervals starting before `before`, when given), in pieces of
        about `rows` intervals."""
        def keep(arr: np.ndarray) -> np.ndarray:
            return arr if before is None else arr[arr[:, 0] < before]
        yield keep(self.prefix)
        j0, j1 = self._copies(None, before)
        step = max(1, rows // max(1, len(self.block)))
        for j in range(j0, j1 + 1, step):
            yield keep(self._tiled(j, min(j1, j + step - 1)))
        yield keep(self.rest)

    def busy(self, lo: int, hi: int) -> int:
        total = int((np.clip(self.prefix[:, 1], lo, hi) - np.clip(self.prefix[:, 0], lo, hi)).sum())
        total += int((np.clip(self.rest[:, 1], lo, hi) - np.clip(self.rest[:, 0], lo, hi)).sum())
        if len(self.block):
            total += int(shifted_overlaps(self.block[:, 0], self.block[:, 1], self.shift.ns,
                                          self.shift.copies, lo, hi).sum())
        return total


def _overlap(arr: np.ndarray, lo: int, hi: int) -> np.ndarray:
    return arr[(arr[:, 1] > lo) & (arr[:, 0] < hi)]


def repeated_list(values: list[int], split: tuple[int, int], shift: Shift) -> np.ndarray:
    """A log of frame numbers (e.g. the frames a task was skipped in), repeated."""
    arr = np.asarray(values, dtype=np.int64)
    block = arr[split[0]:split[1]]
    steps = shift.frames * np.arange(shift.copies + 1, dtype=np.int64)
    blocks = (block[None, :] + steps[:, None]).reshape(-1)
    return np.concatenate([arr[:split[0]], blocks, arr[split[1]:] + shift.copies * shift.frames])
