"""Reading a frame capture into one table of slices, whatever format it came in.

Four formats (docs/frame_captures.md): Chrome trace-event JSON (what Perfetto, the
browsers and several engines' profilers export, and mgpusim's own `trace.perfetto.json`), a
plain CSV (one row per pass), a measured run of the Vulkan runner (a folder with
`trace.parquet` or `trace.csv` and `summary.json`, packed or not), and a RenderDoc capture
(`.rdc`, timed by replaying it: :mod:`.rdc`). Each becomes a
:data:`SLICE_COLUMNS` table: one row per piece of GPU or CPU work with its frame, the queue it
ran on, its time and what it read and wrote. :mod:`mgpusim.frames.importer` turns that
table into a frame. A file that cannot be read as its format is one InputError naming the file
and the field (or row) at fault.
"""
from __future__ import annotations

import csv
import io
import itertools
import math
import re
from array import array
from pathlib import Path
from typing import Any, Iterable, cast

import numpy as np
import pandas as pd

from mgpusim.frames import rdc, trace_json
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_BYTES, MAX_SIDE, MAX_TASK_NS
from mgpusim.validation.measured import TRACE_FILES
from mgpusim.validation.measured_check import check_trace, number_column, read_json_object, read_table

#: One row per piece of work: `queue` is graphics, compute, transfer or cpu; `ms` its time;
#: start/end in ns where the capture has them (NaN in a CSV); `reads`/`writes` resource names;
#: `bytes` one count per written resource (empty: unknown); `view` 0/1 for a stereo frame's
#: eyes (-1: none); `pixel_share` where the capture states it (NaN: the import's default).
SLICE_COLUMNS = ("frame", "queue", "name", "ms", "start_ns", "end_ns", "reads", "writes", "bytes",
                 "view", "pixel_share")
QUEUES = ("graphics", "compute", "transfer", "cpu")
FORMATS = ("chrome", "csv", "run", "renderdoc")

#: Track names (thread, else process) that mean a GPU queue, checked in this order.
_QUEUE_WORDS = (("compute", ("compute", "async")), ("transfer", ("transfer", "copy", "dma")),
                ("graphics", ("graphics", "direct", "3d", "gpu", "render", "queue")))
#: Categories of mgpusim's own exports that are no pass of the frame: every schedule adds its
#: own present, and link tracks hold the links' busy intervals.
_SKIPPED_CATEGORIES = ("present", "link")
_VIEWS = {"left": 0, "right": 1, "0": 0, "1": 1}


def detect_format(path: Path) -> str:
    """chrome (.json), csv (.csv) or run (a folder: a measured run, packed or not)."""
    if run_archive.is_folder(path):
        return "run"
    if path.suffix.lower() == ".json":
        return "chrome"
    if path.suffix.lower() == ".csv":
        return "csv"
    if path.suffix.lower() == ".rdc":
        return "renderdoc"
    raise InputError("cannot tell the capture's format from its name (expected a .json Chrome "
                     "trace, a .csv table, a .rdc RenderDoc capture or a measured run's folder): give "
                     "--format", file=str(path))


def read_capture(path: Path, fmt: str, cpu_threads: Iterable[str] = ("main",)
                 ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The capture's slices and what else it says (`width`/`height` where it knows them, the
    `source` experiment of a measured run, `left_out`: work that is no pass of the frame)."""
    path = resolve_capture(path)
    if fmt == "chrome":
        return read_chrome(path, tuple(cpu_threads))
    if fmt == "csv":
        return read_csv(path)
    if fmt == "run":
        return read_run(path)
    if fmt == "renderdoc":
        return read_renderdoc(path)
    raise InputError(f"must be one of {', '.join(FORMATS)}, got {fmt!r}", field="--format")


#: The example captures: the checkout's examples/frames (through a link), or the wheel's copy.
EXAMPLES = Path(__file__).resolve().parent / "examples"


def resolve_capture(path: Path) -> Path:
    """`path` where anything is there; else, for a checkout's example path
    (`examples/frames/<file>`), the shipped example, so that the README's import runs from a
    wheel install too."""
    try:
        if path.exists() or path.is_symlink():
            return path
    except OSError:  # a name too long: the reader says so
        return path
    text = path.as_posix()
    if "examples/frames/" in text:
        shipped = EXAMPLES / text.split("examples/frames/", 1)[1]
        if shipped.is_file():
            return shipped
    return path


def slices_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Rows as the slice table, in the order given."""
    df = pd.DataFrame(rows, columns=list(SLICE_COLUMNS))
    return df.astype({"frame": "int64", "ms": "float64", "start_ns": "float64", "end_ns": "float64",
                      "view": "int64", "pixel_share": "float64"})


# ----- RenderDoc ----------------------------------------------------------------------------
def read_renderdoc(path: Path, replays: int = rdc.REPLAYS) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A RenderDoc capture's passes, timed over `replays` replays of its frame (:mod:`.rdc`)."""
    rows, meta = rdc.read_rows(path, replays)
    return slices_table(rows), meta


# ----- Chrome trace-event JSON ----------------------------------------------------------------
def read_chrome(path: Path, cpu_threads: tuple[str, ...] = ("main",)) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Complete ("X") events and begin/end ("B"/"E") pairs; tracks named by the metadata
    events. On each track only the innermost slices are work (a slice holding others is a
    group: a frame or a pass group); a group named "frame..." numbers the frames of what it
    holds unless the slices' `args.frame` does. A slice of no length is an instant: no work,
    no group. Events are decoded one at a time (:mod:`.trace_json`) and kept as columns."""
    file = str(path)
    tracks = _Tracks(file)
    text = trace_json.read_text(path, "a Chrome trace (JSON)", MAX_CAPTURE_BYTES)
    top = trace_json.stream_events(text, file, tracks.add)
    del text
    tracks.finish()
    columns, left_out = _chrome_rows(tracks, cpu_threads, file)
    return _columns_table(columns), {"left_out": left_out, **_chrome_size(top, file)}


#: The top-level objects of a Chrome trace where its frame's resolution may be: `width` and
#: `height`, or `resolution` / `size` as "WxH".
SIZE_KEYS = ("metadata", "otherData")


def _chrome_size(data: Any, file: str) -> dict[str, int]:
    """The frame's resolution where the trace's metadata gives it (:data:`SIZE_KEYS`)."""
    if not isinstance(data, dict):
        return {}
    for key in SIZE_KEYS:
        meta = data.get(key)
        if not isinstance(meta, dict):
            continue
        if "width" in meta or "height" in meta:
            return {"width": _side(meta.get("width"), file, f"{key}.width"),
                    "height": _side(meta.get("height"), file, f"{key}.height")}
        for name in ("resolution", "size"):
            if name in meta:
                return _size_text(meta[name], file, f"{key}.{name}")
    return {}


def _side(value: Any, file: str, field: str) -> int:
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value.strip())
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_SIDE:
        raise InputError(f"expected a whole number of pixels 1..65536, got {str(value)[:40]!r}",
                         file=file, field=field)
    return value


def _size_text(value: Any, file: str, field: str) -> dict[str, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value) if isinstance(value, str) else None
    if m is None:
        raise InputError(f"expected WxH, e.g. 1920x1080, got {str(value)[:40]!r}", file=file, field=field)
    return {"width": _side(int(m.group(1)), file, field), "height": _side(int(m.group(2)), file, field)}


#: The largest capture read (a Chrome trace of 10^6 events is about 150 MiB): what lies beyond
#: is a disk image or an endless device given by mistake, refused before memory runs out.
MAX_CAPTURE_BYTES = 1 << 30
#: The latest time read, in the format's microseconds (2^53: 285 years after 1970, where a
#: double still holds a whole microsecond): beyond it a trace was written in ns or ps.
MAX_TS_US = float(2 ** 53)
#: The longest slice read (the model's longest task, 1000 s).
MAX_DUR_US = MAX_TASK_NS / 1000
#: The largest frame number (a double holds it exactly).
MAX_FRAME = 2 ** 53


class _Track:
    """One track's slices, as columns: times in ns from the trace's first event, the event's
    index, its name and category, and its `args` read (or the InputError they make, raised
    only if the slice turns out to be work)."""

    def __init__(self) -> None:
        self.start: array[float] = array("d")
        self.end: array[float] = array("d")
        self.ms: array[float] = array("d")
        self.index: array[int] = array("q")
        self.frame: array[int] = array("q")
        self.name: list[str] = []
        self.cat: list[str] = []
        self.fields: list[tuple[Any, ...] | InputError] = []

    def append(self, start: float, end: float, ms: float,
               item: tuple[int, str, str, int, tuple | InputError]) -> None:
        index, name, cat, frame, fields = item
        self.start.append(start)
        self.end.append(end)
        self.ms.append(ms)
        self.index.append(index)
        self.frame.append(frame)
        self.name.append(name)
        self.cat.append(cat)
        self.fields.append(fields)


class _Tracks:
    """The trace's events gathered by track as they are decoded (:meth:`add`)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.procs: dict[int, str] = {}
        self.names: dict[tuple[int, int], str] = {}
        self.tracks: dict[tuple[int, int], _Track] = {}
        self.open: dict[tuple[int, int], list[tuple[float, float, tuple[Any, ...]]]] = {}
        self.origin: float | None = None
        self.shared: dict[str, str] = {}  # one object for equal names (memory)
        self.args: dict[str, tuple[Any, ...]] = {}  # args read, by their text

    def add(self, ev: Any, i: int) -> None:
        if not isinstance(ev, dict):
            raise InputError(f"expected an event object, got {type(ev).__name__}", file=self.file,
                             field=f"traceEvents[{i}]")
        ph = ev.get("ph")
        if ph == "M":
            _metadata(ev, self.procs, self.names)
        elif ph in ("X", "B", "E"):
            self._slice(ev, ph, i)

    def _slice(self, ev: dict[str, Any], ph: str, i: int) -> None:
        # the hot path of a large capture: plain values checked inline, the rest (and every
        # error) by the field readers
        pid, tid, ts = ev.get("pid", 0), ev.get("tid", 0), cast(Any, ev.get("ts"))
        track = (pid if type(pid) is int else _int_field(ev, "pid", i, self.file),
                 tid if type(tid) is int else _int_field(ev, "tid", i, self.file))
        if not (type(ts) in _NUMBERS and 0 <= ts <= MAX_TS_US):
            ts = _time_field(ev, "ts", i, self.file, MAX_TS_US)
        if self.origin is None:
            self.origin = ts
        if ph == "E":
            self._end(track, ts, i)
        elif ph == "B":
            self.open.setdefault(track, []).append((ts, self._ns(ts), self._item(ev, i)))
        else:
            dur = cast(Any, ev.get("dur"))
            if not (type(dur) in _NUMBERS and 0 <= dur <= MAX_DUR_US):
                dur = _time_field(ev, "dur", i, self.file, MAX_DUR_US)
            start = (ts - cast(float, self.origin)) * 1000.0
            self._track(track).append(start, start + dur * 1000.0, dur / 1000, self._item(ev, i))

    def _end(self, track: tuple[int, int], ts: float, i: int) -> None:
        stack = self.open.get(track)
        if not stack:
            raise InputError("an end event with no begin event open on its track", file=self.file,
                             field=f"traceEvents[{i}]")
        begun, start, item = stack.pop()
        if ts < begun:
            raise InputError("ends before its begin event", file=self.file, field=f"traceEvents[{i}].ts")
        if ts - begun > MAX_DUR_US:
            raise InputError(f"a slice longer than {MAX_DUR_US:g} microseconds (the longest task "
                             "the model runs)", file=self.file, field=f"traceEvents[{i}].ts")
        self._track(track).append(start, self._ns(ts), (ts - begun) / 1000, item)

    def _track(self, track: tuple[int, int]) -> _Track:
        found = self.tracks.get(track)
        if found is None:
            found = self.tracks[track] = _Track()
        return found

    def _ns(self, ts_us: float) -> float:
        """A time as ns after the trace's first one: exact for whole microseconds since 1970
        (whose ns would lose 256 ns to a double's rounding)."""
        if self.origin is None:
            self.origin = ts_us
        return (ts_us - self.origin) * 1000.0

    def _item(self, ev: dict[str, Any], i: int) -> tuple[int, str, str, int, tuple | InputError]:
        shared = self.shared
        name = ev.get("name")
        if not (type(name) is str and name and name.isascii()):
            name = _event_name(ev, i, self.file)
        name = shared.setdefault(name, name)
        cat = ev.get("cat", "")
        cat = shared.setdefault(cat, cat) if type(cat) is str else str(cat)
        args = ev.get("args")
        if type(args) is not dict or not args:
            return i, name, cat, -1, ()
        frame = args.pop("frame", None)
        if frame is None:
            frame = -1
        elif not (type(frame) is int and 0 <= frame <= MAX_FRAME):
            frame = _frame_arg(frame, self.file, f"traceEvents[{i}].args.frame", lazy=True)
        key = repr(args)  # equal args read once: a capture repeats its passes' args every frame
        fields = self.args.get(key)
        if fields is None:
            try:
                fields = self.args[key] = _chrome_args(args, self.file, f"traceEvents[{i}].args")
            except InputError as exc:
                return i, name, cat, -1, exc
        if isinstance(frame, InputError):
            return i, name, cat, -1, frame
        return i, name, cat, frame, fields

    def _shared(self, value: Any) -> Any:
        return self.shared.setdefault(value, value)

    def finish(self) -> None:
        unclosed = [(items[0][2][0], t) for t, items in self.open.items() if items]
        if unclosed:
            raise InputError("a begin event is never ended", file=self.file,
                             field=f"traceEvents[{min(unclosed)[0]}]")


def _event_name(ev: dict[str, Any], i: int, file: str) -> str:
    """The slice's name: a string (a number as its text; none: "(unnamed)"), valid Unicode."""
    name = ev.get("name")
    if name is None:
        return "(unnamed)"
    if isinstance(name, (int, float)) and not isinstance(name, bool):
        return str(name)
    if not isinstance(name, str):
        raise InputError(f"expected a name (a string), got {str(name)[:40]!r}", file=file,
                         field=f"traceEvents[{i}].name")
    if not name.isascii() and _SURROGATE.search(name):
        raise InputError("not valid Unicode: a lone surrogate (\\ud800-\\udfff) in the name", file=file,
                         field=f"traceEvents[{i}].name")
    return name or "(unnamed)"


_NUMBERS = (int, float)
_SURROGATE = re.compile(r"[\ud800-\udfff]")
#: The args a slice's row reads; a NaN in one of them is no value the format has.
_ARGS = ("reads", "writes", "bytes", "view", "pixel_share")


def _chrome_args(args: dict[str, Any], file: str, where: str) -> tuple[Any, ...]:
    """(reads, writes, bytes, view, pixel_share) of a slice."""
    for key in _ARGS:
        value = args.get(key)
        if isinstance(value, float) and math.isnan(value):
            raise InputError("expected a value, got NaN", file=file, field=f"{where}.{key}")
    reads = _names(args.get("reads"), file, f"{where}.reads")
    writes = _names(args.get("writes"), file, f"{where}.writes")
    sizes = _sizes(args.get("bytes") if writes else None, len(writes), file, f"{where}.bytes")
    return (reads, writes, sizes, _view(args.get("view"), file, f"{where}.view"),
            _share(args.get("pixel_share"), file, f"{where}.pixel_share"))


def _frame_arg(value: Any, file: str, field: str, lazy: bool = False) -> Any:
    """A slice's frame number (-1: none given); `lazy`: its error returned, not raised (the
    slice may be no work)."""
    if value is None:
        return -1
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= MAX_FRAME:
        error = InputError(f"expected a frame number (a whole number 0..2^53), got {str(value)[:40]!r}",
                           file=file, field=field)
        if lazy:
            return error
        raise error
    return value


def _metadata(ev: dict[str, Any], procs: dict[int, str], names: dict[tuple[int, int], str]) -> None:
    args = ev.get("args")
    if not isinstance(args, dict):
        args = {}
    name = args.get("name")
    if not isinstance(name, str):
        return
    pid, tid = ev.get("pid"), ev.get("tid")
    if ev.get("name") == "process_name" and isinstance(pid, int):
        procs[pid] = name
    elif ev.get("name") == "thread_name" and isinstance(pid, int) and isinstance(tid, int):
        names[(pid, tid)] = name


def _int_field(ev: dict[str, Any], key: str, i: int, file: str) -> int:
    value = ev.get(key, 0)
    if isinstance(value, str) and value.isdigit():
        return int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise InputError(f"expected an integer, got {str(value)[:40]!r}", file=file,
                         field=f"traceEvents[{i}].{key}")
    return value


def _time_field(ev: dict[str, Any], key: str, i: int, file: str, most: float) -> float:
    """A time in microseconds (the format's unit), 0..`most`."""
    value = ev.get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 <= value <= most:
        unit = " (was the trace written in ns?)" if isinstance(value, (int, float)) and value > most \
            and not isinstance(value, bool) and math.isfinite(value) else ""
        raise InputError(f"expected a finite number of microseconds 0..{most:.4g}, got "
                         f"{str(value)[:40]!r}{unit}", file=file, field=f"traceEvents[{i}].{key}")
    return value


def queue_of_track(process: str, thread: str, cpu_threads: tuple[str, ...]) -> str | None:
    """The queue a track stands for: a CPU thread named in `cpu_threads`, else a GPU queue by
    the words of its thread's (then its process's) name, else None (not frame work: another
    CPU thread, a host copy thread)."""
    if thread in cpu_threads:
        return "cpu"
    for text in (thread, process):
        low = text.lower()
        for queue, words in _QUEUE_WORDS:
            if any(w in low for w in words):
                return queue
    return None


def _chrome_rows(tracks: _Tracks, cpu_threads: tuple[str, ...], file: str
                 ) -> tuple[dict[str, list[Any]], dict[str, float]]:
    """The work slices as the slice table's columns, and what was left out (ms by track)."""
    columns: dict[str, list[Any]] = {c: [] for c in SLICE_COLUMNS}
    left_out: dict[str, float] = {}
    gpus: set[str] = set()
    frame_groups: list[tuple[np.ndarray, np.ndarray]] = []  # (starts, numbers) of a GPU track's frames
    unframed: list[tuple[np.ndarray, np.ndarray]] = []  # (frames, starts) of GPU tracks without any
    for (pid, tid), track in tracks.tracks.items():
        process, thread = tracks.procs.get(pid, f"pid {pid}"), tracks.names.get((pid, tid), "")
        queue = queue_of_track(process, thread, cpu_threads)
        if queue is None or thread.startswith("link"):
            left_out[f"{process}/{thread or tid}"] = float(np.asarray(track.ms).sum())
            continue
        if queue != "cpu":
            gpus.add(process)
        groups = _track_rows(track, queue, f"{process}/{thread}", columns, left_out)
        if queue != "cpu" and len(groups[0]):
            frame_groups.append(groups)
        elif queue != "cpu" and len(columns["frame"][-1]):
            unframed.append((columns["frame"][-1], columns["start_ns"][-1]))
    if frame_groups:
        _frames_from_other_tracks(max(frame_groups, key=lambda g: len(g[0])), unframed)
    if len(gpus) > 1:
        raise InputError(f"GPU work on {len(gpus)} processes ({', '.join(sorted(gpus))}): a frame is "
                         "imported from a one-GPU capture", file=file)
    if not any(chunk[0] in ("graphics", "compute") for chunk in columns["queue"] if chunk):
        raise InputError("no GPU work found: no track's thread or process name says graphics, "
                         "compute, gpu or queue (docs/frame_captures.md)", file=file)
    return columns, left_out


def _frames_from_other_tracks(groups: tuple[np.ndarray, np.ndarray],
                              unframed: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """A GPU track without frame groups (an async-compute queue, whose profiler marks frames on
    the graphics queue only) takes its frames from the track that has them: a slice without a
    frame of its own is in the frame that began last at or before its start (the first, before
    any). Changes the tracks' frame columns in place."""
    starts, numbers = groups
    order = np.argsort(starts, kind="stable")
    starts, numbers = starts[order], numbers[order]
    for frames, begins in unframed:
        free = frames < 0
        at = np.searchsorted(starts, begins[free], side="right") - 1
        frames[free] = numbers[np.maximum(at, 0)]


def _track_rows(track: _Track, queue: str, where: str, columns: dict[str, list[Any]],
                left_out: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """One track's work slices appended to `columns` (as chunks, :func:`_columns_table`); its
    present slices and instants to `left_out`. Returns the track's frame groups (starts and
    frame numbers)."""
    start, end = np.asarray(track.start), np.asarray(track.end)
    instants = int((end <= start).sum())
    if instants:
        left_out[f"{where}: {instants} zero-length slice(s)"] = 0.0
    leaves, frames, groups = _leaves(start, end, np.asarray(track.index), track)
    if not set(track.cat).isdisjoint(_SKIPPED_CATEGORIES):
        kept = [n for n, k in enumerate(leaves) if track.cat[k] not in _SKIPPED_CATEGORIES]
        for k in leaves:
            if track.cat[k] in _SKIPPED_CATEGORIES:
                key = f"{where}: {track.cat[k]}"
                left_out[key] = left_out.get(key, 0.0) + track.ms[k]
        leaves, frames = [leaves[n] for n in kept], [frames[n] for n in kept]
    fields = [track.fields[k] or _NO_FIELDS for k in leaves]
    error = next((f for f in fields if isinstance(f, InputError)), None)
    if error is not None:
        raise error
    at = np.asarray(leaves, dtype=np.int64)
    chunk = {"frame": np.asarray(frames, dtype=np.int64), "queue": [queue] * len(leaves),
             "name": [track.name[k] for k in leaves], "ms": np.asarray(track.ms)[at],
             "start_ns": start[at], "end_ns": end[at]}
    chunk.update(zip(("reads", "writes", "bytes", "view", "pixel_share"),
                     (list(c) for c in zip(*fields)) if fields else ([],) * 5))
    for column in SLICE_COLUMNS:
        columns[column].append(chunk[column])
    return groups


#: The args of a slice that gives none.
_NO_FIELDS = ((), (), (), -1, math.nan)


def _leaves(start: np.ndarray, end: np.ndarray, index: np.ndarray,
            track: _Track) -> tuple[list[int], list[int], tuple[np.ndarray, np.ndarray]]:
    """The innermost slices of one track (positions in it), each with its frame: `args.frame`,
    else the number of the enclosing group named frame* (in order of start), else -1; and the
    frame groups (their starts and numbers). Instants (no length) are neither work nor groups."""
    order = np.lexsort((index, -end, start))
    order = order[end[order] > start[order]]
    s, e = start[order], end[order]
    holds = np.zeros(len(order), dtype=bool)
    holds[:-1] = (s[1:] < e[:-1]) & (e[1:] <= e[:-1])
    leaves: list[int] = []
    frames_of: list[int] = []
    stack: list[tuple[float, int]] = []  # (end, frame number or -1) of the open groups
    frames = 0
    group_starts: list[float] = []
    for k, begins, ends, group in zip(order.tolist(), s.tolist(), e.tolist(), holds.tolist()):
        while stack and stack[-1][0] <= begins:
            stack.pop()
        if group:
            numbered = track.name[k].lower().startswith("frame")
            stack.append((ends, frames if numbered else -1))
            if numbered:
                group_starts.append(begins)
            frames += numbered
            continue
        frame = track.frame[k]
        if frame < 0 and stack:
            frame = next((f for _, f in reversed(stack) if f >= 0), -1)
        leaves.append(k)
        frames_of.append(frame)
    return leaves, frames_of, (np.asarray(group_starts), np.arange(len(group_starts), dtype=np.int64))


def _columns_table(columns: dict[str, list[Any]]) -> pd.DataFrame:
    """The slice table from its columns, each a list of chunks (one a track), as
    :func:`slices_table` makes it from rows."""
    whole = {c: np.concatenate(chunks) if chunks and isinstance(chunks[0], np.ndarray)
             else list(itertools.chain.from_iterable(chunks)) for c, chunks in columns.items()}
    df = pd.DataFrame(whole, columns=list(SLICE_COLUMNS))
    return df.astype({"frame": "int64", "ms": "float64", "start_ns": "float64", "end_ns": "float64",
                      "view": "int64", "pixel_share": "float64"})


# ----- field values shared by the formats -----------------------------------------------------
def _names(value: Any, file: str, field: str) -> tuple[str, ...]:
    """Resource names: a list of strings or one ';'-separated string."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ()
    if isinstance(value, str):
        return tuple(n.strip() for n in value.split(";") if n.strip())
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return tuple(v.strip() for v in value if v.strip())
    raise InputError(f"expected resource names (a list or 'a;b'), got {str(value)[:40]!r}",
                     file=file, field=field)


def _sizes(value: Any, writes: int, file: str, field: str) -> tuple[int, ...]:
    """Bytes of each written resource: one number per write (a list or 'a;b'), or one number
    for a single write; nothing when not given. Each a whole number 0..2^50 (the model's bound
    on a buffer), read exactly (an integer past 2^53 is no double)."""
    if value is None or (isinstance(value, float) and math.isnan(value)) or value == "":
        return ()
    items: list[Any] = value.split(";") if isinstance(value, str) else \
        value if isinstance(value, list) else [value]
    out = [_byte_count(item, file, field) for item in items]
    if len(out) != writes:
        raise InputError(f"{len(out)} byte count(s) for {writes} written resource(s): give one per "
                         "write", file=file, field=field)
    return tuple(out)


def _byte_count(item: Any, file: str, field: str) -> int:
    number: Any = None
    if isinstance(item, int) and not isinstance(item, bool):
        number = item
    elif isinstance(item, float) and item.is_integer():
        number = int(item)
    elif isinstance(item, str):
        text = item.strip()
        try:
            number = int(text) if text.isdigit() else int(float(text)) if float(text).is_integer() else None
        except (ValueError, OverflowError):
            number = None
    if number is None or not 0 <= number <= MAX_BYTES:
        raise InputError(f"expected whole byte counts 0..2^50, got {str(item)[:40]!r}", file=file,
                         field=field)
    return number


def _view(value: Any, file: str, field: str) -> int:
    if value is None or (isinstance(value, float) and math.isnan(value)) or value == "":
        return -1
    key = str(int(value)) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        and float(value).is_integer() else str(value).strip().lower()
    if key not in _VIEWS:
        raise InputError(f"expected 0 or 1 (left or right), got {str(value)[:40]!r}", file=file,
                         field=field)
    return _VIEWS[key]


def _share(value: Any, file: str, field: str) -> float:
    if value is None or (isinstance(value, str) and not value.strip()):
        return math.nan
    try:
        share = float(value)
    except (TypeError, ValueError):
        share = -1.0
    if isinstance(value, float) and math.isnan(value):
        return math.nan
    if isinstance(value, bool) or not 0.0 <= share <= 1.0:
        raise InputError(f"expected a number in [0, 1], got {str(value)[:40]!r}", file=file, field=field)
    return share


# ----- CSV ------------------------------------------------------------------------------------
CSV_REQUIRED = ("pass", "queue", "gpu_ms")
CSV_OPTIONAL = ("reads", "writes", "bytes", "frame", "view", "pixel_share", "width", "height")


def read_csv(path: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """One row per pass (and frame, where a `frame` column repeats them); rows of queue `cpu`
    are the frame's CPU work."""
    file = str(path)
    if path.is_dir():
        raise InputError("is a folder, expected a CSV table", file=file)
    table = read_table(path)
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in CSV_REQUIRED if c not in table.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (columns: {', '.join(CSV_REQUIRED)}, "
                         f"optional {', '.join(CSV_OPTIONAL)})", file=file)
    unknown = [c for c in table.columns if c not in CSV_REQUIRED + CSV_OPTIONAL]
    if unknown:
        raise InputError(f"unknown column {unknown[0]!r} (columns: {', '.join(CSV_REQUIRED + CSV_OPTIONAL)})",
                         file=file)
    if table.empty:
        raise InputError("the table has no rows", file=file)
    _check_csv_shape(table, path)
    ms = number_column(table["gpu_ms"], file, "gpu_ms", minimum=0.0, maximum=1e6)
    frames = number_column(table["frame"], file, "frame", minimum=0, maximum=MAX_FRAME) if "frame" in table else None
    rows = []
    for i, row in enumerate(table.to_dict("records")):
        name, queue = str(row["pass"]).strip(), str(row["queue"]).strip().lower()
        if pd.isna(row["pass"]) or not name:
            raise InputError(f"row {i}: a pass needs a name", file=file, field="pass")
        if queue not in QUEUES:
            raise InputError(f"row {i}: expected one of {', '.join(QUEUES)}, got {str(row['queue'])[:40]!r}",
                             file=file, field="queue")
        frame = 0 if frames is None else cast(float, frames.iat[i])
        if frame != int(frame):
            raise InputError(f"row {i}: expected a whole frame number, got {frame}", file=file, field="frame")
        writes = _names(row.get("writes"), file, f"writes (row {i})")
        rows.append({"frame": int(frame), "queue": queue, "name": name, "ms": float(cast(float, ms.iat[i])),
                     "start_ns": math.nan, "end_ns": math.nan,
                     "reads": _names(row.get("reads"), file, f"reads (row {i})"), "writes": writes,
                     "bytes": _sizes(row.get("bytes"), len(writes), file, f"bytes (row {i})"),
                     "view": _view(row.get("view"), file, f"view (row {i})"),
                     "pixel_share": _share(row.get("pixel_share"), file, f"pixel_share (row {i})")})
    return slices_table(rows), {"left_out": {}, **_csv_size(table, file)}


#: Columns of names: read as the text the file has ("007" stays "007", not 7).
_CSV_TEXT = ("pass", "reads", "writes")


def _check_csv_shape(table: pd.DataFrame, path: Path) -> None:
    """Rows no longer than the header (pandas would make the extra field the row's index and
    shift every field by one), numbers that are no true/false column, names as their text."""
    file = str(path)
    if not isinstance(table.index, pd.RangeIndex):
        raise InputError(f"a row has more fields than the header's {len(table.columns)}", file=file)
    for col in ("gpu_ms", "frame"):
        if col in table and table[col].dtype == bool:
            raise InputError("expected numbers, got true/false", file=file, field=col)
    numeric = [c for c in _CSV_TEXT if c in table and table[c].dtype != object and table[c].notna().any()]
    if numeric:
        texts = _csv_text_columns(path, numeric, len(table))
        for col in numeric:
            table[col] = texts[col] if col in texts else table[col].astype(str)


def _csv_text_columns(path: Path, columns: list[str], rows: int) -> dict[str, list[str | float]]:
    """The cells of `columns` as the file writes them (an empty cell: NaN), where the file's
    rows are the table's."""
    text = trace_json.read_text(path, "a CSV table", MAX_CAPTURE_BYTES)
    lines = [r for r in csv.reader(io.StringIO(text)) if r]
    header = [c.strip() for c in lines[0]]
    if len(lines) - 1 != rows:
        return {}
    return {c: [r[header.index(c)] if r[header.index(c)] != "" else math.nan for r in lines[1:]]
            for c in columns}


def _csv_size(table: pd.DataFrame, file: str) -> dict[str, int]:
    """The frame's resolution from the `width` and `height` columns (both, one value each
    over the rows that give one), where the table has them."""
    have = [c for c in ("width", "height") if c in table.columns]
    if not have:
        return {}
    if len(have) == 1:
        raise InputError(f"a {have[0]} column without its pair: give both width and height", file=file,
                         field=have[0])
    out = {}
    for col in have:
        values = {str(v).strip() for v in table[col] if not pd.isna(v) and str(v).strip()}
        if len(values) != 1:
            raise InputError(f"expected one frame size over the rows, got {sorted(values)[:4] or 'none'}",
                             file=file, field=col)
        text = values.pop()
        number = float(text) if re.fullmatch(r"\d+(?:\.0*)?", text) else math.nan
        out[col] = _side(int(number) if number == number else text, file, col)
    return out


# ----- the runner's measured runs -------------------------------------------------------------
#: Pass kinds of the runner and the share of their time that scales with the pixels they draw:
#: a fragment loop, a filter and particle rendering shade every pixel (their fixed cost aside),
#: a mesh's and a particle update's time goes with triangles and particles.
RUN_PIXEL_SHARE = {"fragment_loop": 1.0, "filter": 1.0, "particle_render": 1.0, "mesh": 0.0,
                   "particle_update": 0.0}
_RUN_SCHEDULES = ("sort_first", "sort_last", "afr", "pipelining", "xr")


def read_run(folder: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A measured run: its render tasks are the passes (the schedule's present is not one);
    what each reads and writes comes from the recorded scene (a filter samples the passes
    before it, AFR's temporal pass its own previous output). A study's folder of repeated runs
    is read as the run it compares (:func:`run_of_folder`); a run on several GPUs where each
    pass of a frame runs whole on one GPU (AFR, pipelining) gives every pass where it ran
    (:data:`MULTI_GPU_SCHEDULES`). Returns `notes` on what was read."""
    folder, notes = run_of_folder(folder)
    file = str(folder)
    trace = next((check_trace(read_table(folder / name), str(folder / name)) for name in TRACE_FILES
                  if run_archive.is_file(folder / name)), None)
    if trace is None:
        raise InputError("no trace.parquet or trace.csv: expected a measured run's folder", file=file)
    summary = folder / "summary.json"
    if not run_archive.is_file(summary):
        raise InputError("no summary.json beside the trace (the run's recorded configuration)", file=file)
    config = read_json_object(summary).get("config")
    if not isinstance(config, dict) or not isinstance(config.get("inputs"), dict):
        raise InputError("no recorded scene (config.inputs): a run recorded by an older runner",
                         file=str(summary), field="config.inputs")
    schedule, gpus = config.get("schedule"), config.get("gpus")
    views = _run_views(config, str(summary))
    _check_run_gpus(schedule, gpus, views, str(summary))
    specs = config["inputs"].get("passes")
    if not isinstance(specs, list) or not specs or not all(isinstance(s, dict) and "name" in s for s in specs):
        raise InputError("expected the scene's passes", file=str(summary), field="config.inputs.passes")
    for i, spec in enumerate(specs):
        if not isinstance(spec["name"], str) or not spec["name"]:
            raise InputError(f"expected a pass's name, got {str(spec['name'])[:40]!r}", file=str(summary),
                             field=f"config.inputs.passes[{i}].name")
    width, height = (_run_side(config.get(k), str(summary), f"config.{k}") for k in ("width", "height"))
    resources = _run_io(specs, config, width * height * 4, str(summary))
    rows = _run_rows(trace, specs, resources, views, file)
    if gpus != 1:
        notes.append(_gpus_note(trace, schedule, cast(int, gpus)))
    source = {"experiment": config.get("experiment"), "file": config.get("file"), "schedule": schedule,
              "run": file, "gpus": gpus}
    why = {str(s["name"]): f"the run's pass kind {s.get('kind')!r}" for s in specs
           if str(s.get("kind", "")) in RUN_PIXEL_SHARE}
    return slices_table(rows), {"width": width, "height": height, "source": source, "left_out": {},
                                "share_why": why, "notes": notes}


#: Schedules whose runs on several GPUs time every pass of a frame whole, on one GPU: AFR (a
#: frame's passes on the GPU whose turn it is), pipelining (each pass on the GPU it is split
#: to). Sort-first and sort-last time each GPU's part of a pass (a tile, a share of the
#: geometry), which is not the pass.
MULTI_GPU_SCHEDULES = ("afr", "pipelining")
#: The subfolder of a study's repeated runs that is read: the steady window the study compares
#: (`steady`), else the first run.
RUN_CHOICES = ("steady", "run0")


def run_of_folder(folder: Path) -> tuple[Path, list[str]]:
    """The run folder to read: `folder` where it holds a trace; else, a study's folder of one
    configuration's repeated runs (run0/, run1/, ... and steady/, on disk or packed), its
    :data:`RUN_CHOICES` subfolder, with a note saying which; else `folder` (whose reader says
    what is missing, naming the runs below it where it holds several)."""
    if _has_trace(folder):
        return folder, []
    for name in RUN_CHOICES:
        if _has_trace(folder / name):
            what = "the steady window of its repeated runs, what the study compares" if name == "steady" \
                else "its first run"
            return folder / name, [f"read {name}/ of the study's run folder {folder.name}: {what}"]
    below = _runs_below(folder)
    if below:
        shown = ", ".join(below[:3]) + (" ..." if len(below) > 3 else "")
        raise InputError(f"no trace here, but {len(below)} run(s) below ({shown}): give one run's folder",
                         file=str(folder))
    return folder, []


def _has_trace(folder: Path) -> bool:
    return any(run_archive.is_file(folder / name) for name in TRACE_FILES)


def _runs_below(folder: Path) -> list[str]:
    """The run folders below `folder` (relative), on disk or in the archive holding it."""
    try:
        if folder.is_dir() and (folder / run_archive.TRACES).is_file():
            return [r.relative_to(folder).as_posix() for r in run_archive.runs_in(folder) if r != folder]
        if folder.is_dir():  # two levels down: a study's runs/<config>/<run>, not a whole disk
            return sorted({t.parent.relative_to(folder).as_posix() for name in TRACE_FILES
                           for pattern in (f"*/{name}", f"*/*/{name}") for t in folder.glob(pattern)})
    except (OSError, InputError):  # a folder that cannot be listed, a damaged archive: the reader says so
        return []
    found = run_archive.archive_of(folder)
    if found is None:
        return []
    archive, rel = found
    return sorted(run[len(rel) + 1:] for run in archive.traces if run.startswith(f"{rel}/"))


def _check_run_gpus(schedule: Any, gpus: Any, views: int, file: str) -> None:
    """A run of a schedule the import reads, on one GPU (any of :data:`_RUN_SCHEDULES`, XR in
    its simulated mode) or, for :data:`MULTI_GPU_SCHEDULES`, on several."""
    if schedule not in _RUN_SCHEDULES:
        raise InputError(f"a frame is imported from a run of {', '.join(_RUN_SCHEDULES)}; this is "
                         f"{str(schedule)[:40]!r}", file=file, field="config.schedule")
    if not isinstance(gpus, int) or isinstance(gpus, bool) or gpus < 1:
        raise InputError(f"expected the run's GPU count, got {str(gpus)[:40]!r}", file=file, field="config.gpus")
    if gpus != 1 and views == 1 and schedule not in MULTI_GPU_SCHEDULES:
        raise InputError(f"a {schedule} run on {gpus} GPUs times each GPU's part of a pass (a tile or a "
                         f"share of the geometry), not the pass: import its one-GPU run, or an "
                         f"{' or '.join(MULTI_GPU_SCHEDULES)} run", file=file, field="config.gpus")


def _gpus_note(trace: pd.DataFrame, schedule: Any, gpus: int) -> str:
    """Where a multi-GPU run's passes ran, for the import's notes."""
    renders = trace[trace["step"] == "render"]
    where = renders.groupby("device", sort=True)["task"].unique()
    shown = "; ".join(f"{device}: {', '.join(_RENDER_PREFIX.sub('', str(t)) for t in tasks)}"
                      for device, tasks in where.items())
    how = {"afr": "each frame on one GPU, in turn", "xr": "each eye on a GPU of its own"}.get(
        str(schedule), "each pass on the GPU it was split to")
    return (f"a run of {schedule} on {gpus} GPUs ({how}; {shown}): every pass is timed whole where it ran, "
            "with the other GPUs busy beside it (on lavapipe they share the host's cores)")


def _run_views(config: dict[str, Any], file: str) -> int:
    """2 for an XR run of both eyes, each whole: both on one GPU (simulated mode) or each on a
    GPU of its own (multi mode on 2 GPUs); else 1."""
    if config.get("schedule") != "xr":
        return 1
    mode, views, gpus = config.get("mode"), config.get("views"), config.get("gpus")
    pixels, width, height = config.get("view_pixels"), config.get("width"), config.get("height")
    frame = width * height if type(width) is int and type(height) is int else None
    whole = not isinstance(pixels, list) or all(p == frame for p in pixels)  # not a part of an eye each
    if views == 2 and (mode == "simulated" or (mode == "multi" and gpus == 2 and whole)):
        return 2
    raise InputError("an XR run is imported with 2 views, each eye whole: both on one GPU (its simulated "
                     "mode) or one per GPU (multi mode on 2 GPUs)", file=file, field="config.mode")


def _run_side(value: Any, file: str, field: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_SIDE:
        raise InputError(f"expected the frame's side, a whole number of pixels 1..{MAX_SIDE}, got "
                         f"{str(value)[:40]!r}", file=file, field=field)
    return value


def _run_count(value: Any, file: str, field: str) -> int:
    """A count the recorded scene gives (a filter's inputs): a whole number >= 0 (JSON may
    hold it as 2.0)."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise InputError(f"expected a whole number >= 0, got {str(value)[:40]!r}", file=file, field=field)
    return value


def _run_io(specs: list[dict[str, Any]], config: dict[str, Any],
            image_bytes: int, file: str) -> dict[str, tuple[tuple[str, ...], int]]:
    """Pass -> (the passes it reads, bytes of its output image): each pass renders one RGBA8
    image (`output_bytes` where the scene gives it), a filter samples the `inputs` passes
    before it, AFR's temporal pass also its own output of the previous frame, and pipelining's
    `reads` table what it lists."""
    names = [str(s["name"]) for s in specs]
    schedule_inputs = config["inputs"].get("schedule") if isinstance(config["inputs"].get("schedule"), dict) else {}
    listed = schedule_inputs.get("reads")
    if not isinstance(listed, dict):
        listed = {}
    for name, reads_of in listed.items():
        if not isinstance(reads_of, list) or not all(isinstance(r, str) for r in reads_of):
            raise InputError(f"expected a list of pass names, got {str(reads_of)[:40]!r}", file=file,
                             field=f"config.inputs.schedule.reads.{name}")
    temporal = schedule_inputs.get("temporal_pass") or config.get("temporal_pass") or ""
    out = {}
    for i, spec in enumerate(specs):
        reads: list[str] = []
        if spec.get("kind") == "filter":
            k = _run_count(spec.get("inputs", 1), file, f"config.inputs.passes[{i}].inputs")
            reads = names[max(0, i - k):i]
        reads += [r for r in listed.get(names[i], []) if r in names and r not in reads]
        if names[i] == temporal and names[i] not in reads:
            reads.append(names[i])
        size = spec.get("output_bytes") or image_bytes
        out[names[i]] = (tuple(reads), _byte_count(size, file, f"config.inputs.passes[{i}].output_bytes"))
    return out


_RENDER_PREFIX = re.compile(r"^render\d*\.")
_RENDER_TASK = re.compile(r"^render(?P<view>\d*)(?:\.(?P<name>.+))?$")


def _run_rows(trace: pd.DataFrame, specs: list[dict[str, Any]],
              io: dict[str, tuple[tuple[str, ...], int]], views: int, file: str) -> list[dict[str, Any]]:
    kinds = {str(s["name"]): str(s.get("kind", "")) for s in specs}
    single = next(iter(kinds)) if len(kinds) == 1 else None
    rows = []
    r: Any  # a row's fields (pandas-stubs types each as any scalar)
    for r in trace[trace["step"] == "render"].itertuples(index=False):
        m = _RENDER_TASK.match(str(r.task))
        name = (m.group("name") or single) if m else None
        if m is None or name not in kinds:
            raise InputError(f"render task {r.task!r} names no pass of the recorded scene", file=file)
        view = int(m.group("view")) if views == 2 and m.group("view") else -1
        reads, size = io[name]
        rows.append({"frame": int(r.frame), "queue": "graphics", "name": name,
                     "ms": (r.end_ns - r.start_ns) / 1e6, "start_ns": float(r.start_ns),
                     "end_ns": float(r.end_ns), "reads": reads, "writes": (name,), "bytes": (size,),
                     "view": view, "pixel_share": RUN_PIXEL_SHARE.get(kinds[name], math.nan)})
    if not rows:
        raise InputError("the trace has no render tasks", file=file)
    return rows
