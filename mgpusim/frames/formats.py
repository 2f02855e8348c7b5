"""Reading a frame capture into one table of slices, whatever format it came in.

Three formats (docs/frame_captures.md): Chrome trace-event JSON (what Perfetto, the
browsers and several engines' profilers export, and mgpusim's own `trace.perfetto.json`), a
plain CSV (one row per pass), and a measured run of the Vulkan runner (a folder with
`trace.parquet` or `trace.csv` and `summary.json`, packed or not). Each becomes a
:data:`SLICE_COLUMNS` table: one row per piece of GPU or CPU work with its frame, the queue it
ran on, its time and what it read and wrote. :mod:`mgpusim.frames.importer` turns that
table into a frame. A file that cannot be read as its format is one InputError naming the file
and the field (or row) at fault.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Iterable, cast

import pandas as pd

from mgpusim.io import table_files
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.validation.measured import TRACE_FILES
from mgpusim.validation.measured_check import check_trace, number_column, read_json_object, read_table

#: One row per piece of work: `queue` is graphics, compute, transfer or cpu; `ms` its time;
#: start/end in ns where the capture has them (NaN in a CSV); `reads`/`writes` resource names;
#: `bytes` one count per written resource (empty: unknown); `view` 0/1 for a stereo frame's
#: eyes (-1: none); `pixel_share` where the capture states it (NaN: the import's default).
SLICE_COLUMNS = ("frame", "queue", "name", "ms", "start_ns", "end_ns", "reads", "writes", "bytes",
                 "view", "pixel_share")
QUEUES = ("graphics", "compute", "transfer", "cpu")
FORMATS = ("chrome", "csv", "run")

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
    raise InputError("cannot tell the capture's format from its name (expected a .json Chrome "
                     "trace, a .csv table or a measured run's folder): give --format", file=str(path))


def read_capture(path: Path, fmt: str, cpu_threads: Iterable[str] = ("main",)
                 ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The capture's slices and what else it says (`width`/`height` where it knows them, the
    `source` experiment of a measured run, `left_out`: work that is no pass of the frame)."""
    if fmt == "chrome":
        return read_chrome(path, tuple(cpu_threads))
    if fmt == "csv":
        return read_csv(path)
    if fmt == "run":
        return read_run(path)
    raise InputError(f"must be one of {', '.join(FORMATS)}, got {fmt!r}", field="--format")


def slices_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Rows as the slice table, in the order given."""
    df = pd.DataFrame(rows, columns=list(SLICE_COLUMNS))
    return df.astype({"frame": "int64", "ms": "float64", "start_ns": "float64", "end_ns": "float64",
                      "view": "int64", "pixel_share": "float64"})


# ----- Chrome trace-event JSON ----------------------------------------------------------------
def read_chrome(path: Path, cpu_threads: tuple[str, ...] = ("main",)) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Complete ("X") events and begin/end ("B"/"E") pairs; tracks named by the metadata
    events. On each track only the innermost slices are work (a slice holding others is a
    group: a frame or a pass group); a group named "frame..." numbers the frames of what it
    holds unless the slices' `args.frame` does."""
    file = str(path)
    data = _chrome_data(path)
    events = _chrome_events(data, file)
    names: dict[tuple[int, int], str] = {}
    procs: dict[int, str] = {}
    spans: dict[tuple[int, int], list[dict[str, Any]]] = {}
    open_: dict[tuple[int, int], list[dict[str, Any]]] = {}
    for i, ev in enumerate(events):
        if not isinstance(ev, dict):
            raise InputError(f"expected an event object, got {type(ev).__name__}", file=file,
                             field=f"traceEvents[{i}]")
        ph = ev.get("ph")
        if ph == "M":
            _metadata(ev, procs, names)
            continue
        if ph not in ("X", "B", "E"):
            continue
        track = (_int_field(ev, "pid", i, file), _int_field(ev, "tid", i, file))
        if ph == "E":
            stack = open_.get(track)
            if not stack:
                raise InputError("an end event with no begin event open on its track", file=file,
                                 field=f"traceEvents[{i}]")
            begun = stack.pop()
            begun["end"] = _time_field(ev, "ts", i, file)
            if begun["end"] < begun["start"]:
                raise InputError("ends before its begin event", file=file, field=f"traceEvents[{i}].ts")
            spans.setdefault(track, []).append(begun)
            continue
        start = _time_field(ev, "ts", i, file)
        item: dict[str, Any] = {"name": str(ev.get("name", "")), "cat": str(ev.get("cat", "")), "start": start,
                                "args": ev.get("args") if isinstance(ev.get("args"), dict) else {}, "index": i}
        if ph == "B":
            open_.setdefault(track, []).append(item)
            continue
        item["end"] = start + _time_field(ev, "dur", i, file)
        spans.setdefault(track, []).append(item)
    unclosed = [t for t, stack in open_.items() if stack]
    if unclosed:
        first = open_[unclosed[0]][0]
        raise InputError("a begin event is never ended", file=file,
                         field=f"traceEvents[{first['index']}]")
    rows, left_out = _chrome_rows(spans, procs, names, cpu_threads, file)
    return slices_table(rows), {"left_out": left_out, **_chrome_size(data, file)}


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
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= 65536:
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


def _chrome_data(path: Path) -> Any:
    """The trace file's JSON (a capture may be far larger than a record: up to MAX_CAPTURE_BYTES)."""
    return table_files.read_json(path, "a Chrome trace (JSON)", MAX_CAPTURE_BYTES)


def _chrome_events(data: Any, file: str) -> list[Any]:
    """The trace's events: an object's `traceEvents`, or the bare list."""
    events = data.get("traceEvents") if isinstance(data, dict) else data
    if not isinstance(events, list):
        raise InputError("expected a list of events or an object with a traceEvents list",
                         file=file, field="traceEvents")
    return events


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


def _time_field(ev: dict[str, Any], key: str, i: int, file: str) -> float:
    """A time in microseconds (the format's unit), as ns."""
    value = ev.get(key)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) \
            or value < 0:
        raise InputError(f"expected a finite number of microseconds >= 0, got {str(value)[:40]!r}",
                         file=file, field=f"traceEvents[{i}].{key}")
    return float(value) * 1000.0


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


def _chrome_rows(spans: dict[tuple[int, int], list[dict[str, Any]]], procs: dict[int, str],
                 names: dict[tuple[int, int], str], cpu_threads: tuple[str, ...], file: str
                 ) -> tuple[list[dict[str, Any]], dict[str, float]]:
    rows: list[dict[str, Any]] = []
    left_out: dict[str, float] = {}
    gpus: set[str] = set()
    for (pid, tid), items in spans.items():
        process, thread = procs.get(pid, f"pid {pid}"), names.get((pid, tid), "")
        queue = queue_of_track(process, thread, cpu_threads)
        if queue is None or thread.startswith("link"):
            left_out[f"{process}/{thread or tid}"] = sum(s["end"] - s["start"] for s in items) / 1e6
            continue
        if queue != "cpu":
            gpus.add(process)
        for item, frame in _leaves(items):
            if item["cat"] in _SKIPPED_CATEGORIES:
                key = f"{process}/{thread}: {item['cat']}"
                left_out[key] = left_out.get(key, 0.0) + (item["end"] - item["start"]) / 1e6
                continue
            rows.append(_chrome_row(item, queue, frame, file))
    if len(gpus) > 1:
        raise InputError(f"GPU work on {len(gpus)} processes ({', '.join(sorted(gpus))}): a frame is "
                         "imported from a one-GPU capture", file=file)
    if not any(r["queue"] in ("graphics", "compute") for r in rows):
        raise InputError("no GPU work found: no track's thread or process name says graphics, "
                         "compute, gpu or queue (docs/frame_captures.md)", file=file)
    return rows, left_out


def _leaves(items: list[dict[str, Any]]) -> list[tuple[dict[str, Any], int]]:
    """The innermost slices of one track, each with its frame: `args.frame`, else the number of
    the enclosing group named frame* (in order of start), else -1."""
    items = sorted(items, key=lambda s: (s["start"], -s["end"], s["index"]))
    out: list[tuple[dict[str, Any], int]] = []
    stack: list[dict[str, Any]] = []
    frames = 0
    for i, item in enumerate(items):
        while stack and stack[-1]["end"] <= item["start"]:
            stack.pop()
        nxt = items[i + 1] if i + 1 < len(items) else None
        holds = nxt is not None and nxt["start"] < item["end"] and nxt["end"] <= item["end"]
        if holds:
            if item["name"].lower().startswith("frame"):
                item["frame_no"] = frames
                frames += 1
            stack.append(item)
            continue
        out.append((item, _frame_of(item, stack)))
    return out


def _frame_of(item: dict[str, Any], stack: list[dict[str, Any]]) -> int:
    frame = item["args"].get("frame")
    if isinstance(frame, int) and not isinstance(frame, bool) and frame >= 0:
        return frame
    for group in reversed(stack):
        if "frame_no" in group:
            return group["frame_no"]
    return -1


def _chrome_row(item: dict[str, Any], queue: str, frame: int, file: str) -> dict[str, Any]:
    args, where = item["args"], f"traceEvents[{item['index']}].args"
    reads = _names(args.get("reads"), file, f"{where}.reads")
    writes = _names(args.get("writes"), file, f"{where}.writes")
    sizes = _sizes(args.get("bytes") if writes else None, len(writes), file, f"{where}.bytes")
    return {"frame": frame, "queue": queue, "name": item["name"] or "(unnamed)",
            "ms": (item["end"] - item["start"]) / 1e6, "start_ns": item["start"], "end_ns": item["end"],
            "reads": reads, "writes": writes, "bytes": sizes,
            "view": _view(args.get("view"), file, f"{where}.view"),
            "pixel_share": _share(args.get("pixel_share"), file, f"{where}.pixel_share")}


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
    for a single write; nothing when not given."""
    if value is None or (isinstance(value, float) and math.isnan(value)) or value == "":
        return ()
    items: list[Any] = value.split(";") if isinstance(value, str) else \
        value if isinstance(value, list) else [value]
    out = []
    for item in items:
        try:
            number = float(item)
        except (TypeError, ValueError):
            number = math.nan
        if isinstance(item, bool) or not math.isfinite(number) or number < 0 or number != int(number):
            raise InputError(f"expected whole byte counts >= 0, got {str(item)[:40]!r}", file=file,
                             field=field)
        out.append(int(number))
    if len(out) != writes:
        raise InputError(f"{len(out)} byte count(s) for {writes} written resource(s): give one per "
                         "write", file=file, field=field)
    return tuple(out)


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
    ms = number_column(table["gpu_ms"], file, "gpu_ms", minimum=0.0, maximum=1e6)
    frames = number_column(table["frame"], file, "frame", minimum=0) if "frame" in table else None
    rows = []
    for i, row in enumerate(table.to_dict("records")):
        name, queue = str(row["pass"]).strip(), str(row["queue"]).strip().lower()
        if not name or name == "nan":
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
    """A one-GPU measured run: its render tasks are the passes (the schedule's present is not
    one); what each reads and writes comes from the recorded scene (a filter samples the passes
    before it, AFR's temporal pass its own previous output)."""
    file = str(folder)
    trace = None
    for name in TRACE_FILES:
        if run_archive.is_file(folder / name):
            trace = check_trace(read_table(folder / name), str(folder / name))
            break
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
    if schedule not in _RUN_SCHEDULES or (gpus != 1 and views == 1):
        raise InputError(f"a frame is imported from a one-GPU run of {', '.join(_RUN_SCHEDULES)} "
                         f"(or XR's simulated mode); this is {schedule} on {gpus} GPU(s)",
                         file=str(summary), field="config")
    specs = config["inputs"].get("passes")
    if not isinstance(specs, list) or not specs or not all(isinstance(s, dict) and "name" in s for s in specs):
        raise InputError("expected the scene's passes", file=str(summary), field="config.inputs.passes")
    width, height = config.get("width"), config.get("height")
    if not isinstance(width, int) or not isinstance(height, int) or width < 1 or height < 1:
        raise InputError("expected the frame's width and height", file=str(summary), field="config.width")
    io = _run_io(specs, config, width * height * 4)
    rows = _run_rows(trace, specs, io, views, file)
    source = {"experiment": config.get("experiment"), "file": config.get("file"), "schedule": schedule,
              "run": file}
    why = {str(s["name"]): f"the run's pass kind {s.get('kind')!r}" for s in specs
           if str(s.get("kind", "")) in RUN_PIXEL_SHARE}
    return slices_table(rows), {"width": width, "height": height, "source": source, "left_out": {},
                                "share_why": why}


def _run_views(config: dict[str, Any], file: str) -> int:
    """2 for an XR run of both views on one GPU, else 1."""
    if config.get("schedule") != "xr":
        return 1
    if config.get("mode") != "simulated" or config.get("views") != 2:
        raise InputError("an XR run is imported from its simulated mode with 2 views (both eyes on "
                         "one GPU)", file=file, field="config.mode")
    return 2


def _run_io(specs: list[dict[str, Any]], config: dict[str, Any],
            image_bytes: int) -> dict[str, tuple[tuple[str, ...], int]]:
    """Pass -> (the passes it reads, bytes of its output image): each pass renders one RGBA8
    image (`output_bytes` where the scene gives it), a filter samples the `inputs` passes
    before it, AFR's temporal pass also its own output of the previous frame, and pipelining's
    `reads` table what it lists."""
    names = [str(s["name"]) for s in specs]
    schedule_inputs = config["inputs"].get("schedule") if isinstance(config["inputs"].get("schedule"), dict) else {}
    listed = schedule_inputs.get("reads")
    if not isinstance(listed, dict):
        listed = {}
    temporal = schedule_inputs.get("temporal_pass") or config.get("temporal_pass") or ""
    out = {}
    for i, spec in enumerate(specs):
        reads: list[str] = []
        if spec.get("kind") == "filter":
            k = int(spec.get("inputs", 1))
            reads = names[max(0, i - k):i]
        reads += [r for r in listed.get(names[i], []) if r in names and r not in reads]
        if names[i] == temporal and names[i] not in reads:
            reads.append(names[i])
        out[names[i]] = (tuple(reads), int(spec.get("output_bytes") or image_bytes))
    return out


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
