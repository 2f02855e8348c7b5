"""Writing a run's results to a folder (the edge of the program: files live here only)."""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pandas as pd

from mgpusim.io.defaults import TRACE_FRAMES
from mgpusim.io.perfetto import chrome_trace_json
from mgpusim.io.plot import timeline_png
from mgpusim.results.summary import Result
from mgpusim.results.trace import make_trace

#: Frames the Perfetto trace covers by default (the last ones): enough to see steady state,
#: small enough that the UI opens it at once whatever the run's length.


def write_table(df: pd.DataFrame, path: Path) -> Path:
    """CSV or Parquet by the file's extension."""
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False)
    return path


def write_trace(result: Result, path: Path, rows_per_group: int = 250_000) -> Path:
    """The whole trace, streamed in sorted row groups when the run kept it compact (a long
    fast-forwarded run never holds it whole); CSV or Parquet by the file's extension."""
    if not result.compact:
        return write_table(result.trace, path)
    import pyarrow as pa  # noqa: PLC0415
    schema = pa.Schema.from_pandas(make_trace([]), preserve_index=False)
    return _stream(result.repeated.arrow_chunks(schema, rows_per_group), schema, path)


def write_links(result: Result, path: Path, rows_per_group: int = 1_000_000) -> Path:
    """The links table, streamed channel by channel when the run kept it compact (a long
    fast-forwarded run's links, 10+ intervals a frame, are never held whole)."""
    if result.compact_links is None or not callable(result._links):
        return write_table(result.links, path)
    import pyarrow as pa  # noqa: PLC0415
    schema = pa.Schema.from_pandas(next(result.links_chunks()).iloc[:0], preserve_index=False)
    tables = (pa.Table.from_pandas(df, schema=schema, preserve_index=False)
              for df in result.links_chunks(rows_per_group))
    return _stream(tables, schema, path)


def _stream(tables: Iterator[Any], schema: Any, path: Path) -> Path:
    """Arrow tables into one Parquet or CSV file (by extension), whole or not at all."""
    import pyarrow.csv as pcsv  # noqa: PLC0415
    import pyarrow.parquet as pq  # noqa: PLC0415
    tmp = path.with_name(path.name + ".tmp")
    writer_class = pq.ParquetWriter if path.suffix == ".parquet" else pcsv.CSVWriter
    with writer_class(tmp, schema) as writer:
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


def write_result(result: Result, out: Path, trace_format: str = "parquet", title: str = "",
                 frames: range | None = None, trace_frames: int = TRACE_FRAMES) -> dict[str, Path]:
    """summary.json, trace + frames + links tables (whole run), timeline.png of `frames`
    (default: the last four) and trace.perfetto.json of the last `trace_frames` frames (0 = all).

    Written into a temporary folder beside `out` and moved in at the end: a run that fails
    while writing (out of memory, disk full, interrupted) leaves no partial folder."""
    with staged_folder(out) as folder:
        files = _write_files(result, folder, trace_format, title, frames, trace_frames)
    return {key: out / path.name for key, path in files.items()}


def _write_files(result: Result, out: Path, trace_format: str, title: str, frames: range | None,
                 trace_frames: int) -> dict[str, Path]:
    files = {
        "summary": write_json({**result.summary, "config": result.config}, out / "summary.json"),
        "trace": write_trace(result, out / f"trace.{trace_format}"),
        "frames": write_table(result.frames, out / f"frames.{trace_format}"),
        "links": write_links(result, out / f"links.{trace_format}"),
    }
    if result.compact:  # a long fast-forwarded run: take the windows without the whole trace
        n = len(result.frames)
        shown = frames if frames is not None else range(max(0, n - 4), n)
        window = result.trace_window(shown.start, shown.stop)
        files["timeline"] = timeline_png(window, out / "timeline.png", _links_over(result, window), title,
                                         list(shown), channels=result.link_channels)
        first = max(0, n - trace_frames) if trace_frames > 0 else 0
        window = result.trace_window(first, n)
        trace, links = frame_window(window, _links_over(result, window), last=trace_frames)
        files["perfetto"] = write_text(chrome_trace_json(trace, links, title), out / "trace.perfetto.json")
    elif len(result.trace):
        files["timeline"] = timeline_png(result.trace, out / "timeline.png", result.links, title,
                                         list(frames) if frames is not None else None)
        trace, links = frame_window(result.trace, result.links, last=trace_frames)
        files["perfetto"] = write_text(chrome_trace_json(trace, links, title), out / "trace.perfetto.json")
    return files


def _links_over(result: Result, trace: pd.DataFrame) -> pd.DataFrame:
    """The link intervals over the time `trace` spans (what its timeline or Perfetto window
    can show), from a long run's compact links."""
    if not len(trace):
        return result.links_window(0, 0)
    return result.links_window(int(trace["start_ns"].min()), int(trace["end_ns"].max()))


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
