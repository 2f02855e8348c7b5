"""Writing a run's results to a folder (the edge of the program: files live here only)."""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np
import pandas as pd

from mgpusim.io.defaults import PERFETTO_SLICES, TRACE_FRAMES, TRACE_ROWS
from mgpusim.io.perfetto import chrome_trace_json
from mgpusim.io.plot import timeline_png
from mgpusim.results.summary import Result
from mgpusim.results.trace import TRACE_COLUMNS, TRACE_DTYPES


def write_table(df: pd.DataFrame, path: Path) -> Path:
    """CSV or Parquet by the file's extension."""
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False)
    return path


def write_trace(result: Result, path: Path, rows_per_group: int = 250_000,
                frames: int | None = None) -> Path:
    """The trace (of the first `frames` frames; None: the whole run), streamed in sorted row
    groups when the run kept it compact (a long fast-forwarded run never holds it whole); CSV
    or Parquet by the file's extension. Parquet stores the text columns dictionary-encoded
    (each distinct value once per row group; a reader gets plain strings) and the numbers
    delta-encoded: `waits_for` goes from the run's codes to the file without a string per row."""
    import pyarrow as pa  # noqa: PLC0415
    csv = path.suffix != ".parquet"
    schema = trace_file_schema(text=csv)
    if not result.compact:
        trace = result.trace if frames is None else result.trace[result.trace["frame"] < frames]
        if csv:
            return write_table(trace, path)
        table = pa.Table.from_pandas(trace, preserve_index=False).replace_schema_metadata(None)
        return _write_arrow([table.cast(schema)], schema, path)
    assert result.repeated is not None  # compact: kept as the repeated rows
    return _write_arrow(result.repeated.arrow_chunks(schema, rows_per_group, frames), schema, path)


def rows_per_frame(result: Result) -> np.ndarray:
    """How many trace rows each frame has (without building a compact trace)."""
    if result.compact:
        assert result.repeated is not None  # compact: kept as the repeated rows
        return result.repeated.rows_per_frame(len(result.frames))
    return np.bincount(result.trace["frame"].to_numpy(np.int64), minlength=len(result.frames))


def table_frames(result: Result, max_rows: int = TRACE_ROWS) -> int:
    """How many first frames the trace table holds: all of them when the run has at most
    `max_rows` rows (0: no bound), else as many whole frames as fit (at least one)."""
    n = len(result.frames)
    if max_rows <= 0:
        return n
    total = np.cumsum(rows_per_frame(result))
    return n if not len(total) or total[-1] <= max_rows else max(1, int(np.searchsorted(total, max_rows, "right")))


def perfetto_frames(result: Result, trace_frames: int | None = None) -> int:
    """How many last frames the Perfetto trace holds: `trace_frames` (0: all); by default
    TRACE_FRAMES, or fewer where those hold more than PERFETTO_SLICES task slices."""
    n = len(result.frames)
    if trace_frames is not None:
        return n if trace_frames <= 0 else min(trace_frames, n)
    counts = rows_per_frame(result)[::-1]
    fit = int(np.searchsorted(np.cumsum(counts), PERFETTO_SLICES, "right"))
    return max(1, min(TRACE_FRAMES, n, fit))


def trace_file_schema(text: bool = False) -> Any:
    """The Arrow schema trace files are written with: int64 numbers; text columns as
    dictionaries (`text`: as plain strings, for CSV)."""
    import pyarrow as pa  # noqa: PLC0415
    kind = pa.large_string() if text else pa.dictionary(pa.int32(), pa.large_string())
    return pa.schema([(c, pa.int64() if TRACE_DTYPES[c] == "int64" else kind) for c in TRACE_COLUMNS])


def _write_arrow(tables: Iterable[Any], schema: Any, path: Path) -> Path:
    """Arrow tables to one Parquet or CSV file, written whole or not at all."""
    import pyarrow as pa  # noqa: PLC0415
    import pyarrow.csv as pcsv  # noqa: PLC0415
    import pyarrow.parquet as pq  # noqa: PLC0415
    tmp = path.with_name(path.name + ".tmp")
    if path.suffix == ".parquet":
        numbers = [f.name for f in schema if f.type == pa.int64()]
        text = [f.name for f in schema if f.name not in numbers]
        # numbers delta-encoded (sorted times, frames: a tenth of the size, written faster),
        # statistics only where a reader filters (numbers; not 100 kB input lists)
        writer = pq.ParquetWriter(tmp, schema, store_schema=False, use_dictionary=text,
                                  column_encoding={c: "DELTA_BINARY_PACKED" for c in numbers},
                                  write_statistics=numbers)
    else:
        writer = pcsv.CSVWriter(tmp, schema)
    with writer:
        for table in tables:
            writer.write_table(table)
    tmp.replace(path)
    return path


def write_json(obj: Any, path: Path) -> Path:
    """Strict JSON (NaN and infinities become null), written whole or not at all."""
    return write_text(json.dumps(_finite(obj), indent=2, sort_keys=True, default=_jsonable,
                                 allow_nan=False) + "\n", path)


def _finite(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item() if getattr(value, "ndim", 0) == 0 else value
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _jsonable(value: Any) -> Any:
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, (set, tuple)):
        return list(value)
    return str(value)


def write_measured(result: Any, out: Path, trace_format: str = "csv") -> Path:
    """A measured run (`mgpusim.real.runner.RunResult`) as `validate --measured` reads it: trace,
    frames, the host side of its submissions (when it has any), summary.json with the
    configuration, machine.json."""
    out.mkdir(parents=True, exist_ok=True)
    write_table(result.trace, out / f"trace.{trace_format}")
    write_table(result.frames, out / f"frames.{trace_format}")
    if result.submissions is not None and len(result.submissions):
        write_table(result.submissions, out / f"submissions.{trace_format}")
    write_json({**result.summary, "config": result.config}, out / "summary.json")
    write_json(result.machine, out / "machine.json")
    return out


def frame_window(trace: pd.DataFrame, links: pd.DataFrame | None,
                 last: int = TRACE_FRAMES) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """The trace rows of the `last` frames (0 = all) and the link busy intervals that overlap
    their time span."""
    if last <= 0 or not len(trace):
        return trace, links
    rows = trace[trace["frame"] > int(trace["frame"].max()) - last]
    if links is None or not len(links) or not len(rows):
        return rows, links
    lo, hi = int(rows["start_ns"].min()), int(rows["end_ns"].max())
    return rows, links[(links["end_ns"] > lo) & (links["start_ns"] < hi)]


def write_text(text: str, path: Path) -> Path:
    """A text file written whole or not at all."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def append_rows(path: Path, old: pd.DataFrame, rows: Iterable[dict[str, Any]],
                columns: Iterable[str]) -> Path:
    """`old` (the table at `path` as read) with `rows` added, written back whole or not at
    all: a job killed while writing keeps the rows before (a job's probe and speed tables)."""
    new = pd.DataFrame(list(rows), columns=list(columns))
    table = pd.concat([old, new] if not old.empty else [new], ignore_index=True)
    return write_text(table.to_csv(index=False), path)


def write_result(result: Result, out: Path, trace_format: str = "parquet", title: str = "",
                 frames: range | None = None, trace_frames: int | None = None,
                 trace_rows: int = TRACE_ROWS,
                 progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """summary.json, the trace table (its first frames within `trace_rows` rows, see
    :func:`table_frames`) and the links table over the same time, the frames table (whole
    run), timeline.png of `frames` (default: the last four) and trace.perfetto.json of the
    last frames (:func:`perfetto_frames` of `trace_frames`). Nothing is built whole that the
    files do not hold: a fast-forwarded run's windows come from its compact logs.
    `progress(name)`: called before each file is written.

    Written into a temporary folder beside `out` and moved in at the end: a run that fails
    while writing (out of memory, disk full, interrupted) leaves no partial folder."""
    with staged_folder(out) as folder:
        files = _write_files(result, folder, trace_format, title, frames, trace_frames, trace_rows,
                             progress or (lambda _name: None))
    return {key: out / path.name for key, path in files.items()}


def _write_files(result: Result, out: Path, trace_format: str, title: str, frames: range | None,
                 trace_frames: int | None, trace_rows: int, say: Callable[[str], None]) -> dict[str, Path]:
    n, kept = len(result.frames), table_frames(result, trace_rows)
    until = None if kept >= n else int(result.frames["present_ns"].iloc[:kept].max()) + 1
    say("summary.json")
    files = {"summary": write_json({**result.summary, "config": result.config}, out / "summary.json")}
    say(f"trace.{trace_format}")
    files["trace"] = write_trace(result, out / f"trace.{trace_format}", frames=kept if kept < n else None)
    say(f"frames.{trace_format}")
    files["frames"] = write_table(result.frames, out / f"frames.{trace_format}")
    say(f"links.{trace_format}")
    files["links"] = write_links(result, out / f"links.{trace_format}", until)
    if result.compact or len(result.trace):
        say("timeline.png")
        shown = frames if frames is not None else range(max(0, n - 4), n)
        rows = result.trace_window(shown.start, shown.stop)
        files["timeline"] = timeline_png(rows, out / "timeline.png", links_over(result, rows), title, list(shown))
        say("trace.perfetto.json")
        rows = result.trace_window(n - perfetto_frames(result, trace_frames), n)
        files["perfetto"] = write_text(chrome_trace_json(rows, links_over(result, rows), title),
                                       out / "trace.perfetto.json")
    return files


def links_over(result: Result, rows: pd.DataFrame) -> pd.DataFrame:
    """The link busy intervals that overlap the time span of `rows` (trace rows)."""
    if not len(rows):
        return result.links_window(0, 0)
    return result.links_window(int(rows["start_ns"].min()), int(rows["end_ns"].max()))


def write_links(result: Result, path: Path, before: int | None = None) -> Path:
    """The links table (only intervals starting before `before`, when given), streamed from a
    fast-forwarded run's compact logs."""
    import pyarrow as pa  # noqa: PLC0415
    schema = pa.schema([("channel", pa.large_string()), ("start_ns", pa.int64()), ("end_ns", pa.int64())])
    tables = (pa.Table.from_pandas(df, preserve_index=False).replace_schema_metadata(None).cast(schema)
              for df in result.links_chunks(before))
    return _write_arrow(tables, schema, path)


@contextmanager
def staged_folder(out: Path) -> Iterator[Path]:
    """A temporary folder beside `out` to write into; on success its files move into `out`
    (created, or its files of the same names replaced), on failure it is removed, with any
    parent folder it had to create."""
    missing = next((p for p in reversed([out.parent, *out.parent.parents]) if not p.exists()), None)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        yield tmp
        if not out.exists():
            tmp.rename(out)
            return
        for path in tmp.iterdir():
            os.replace(path, out / path.name)
        tmp.rmdir()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if missing is not None and not out.exists():
            shutil.rmtree(missing, ignore_errors=True)
        raise
