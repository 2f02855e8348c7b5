"""Writing a run's results to a folder (the edge of the program: files live here only)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pandas as pd

from .perfetto import chrome_trace
from .plot import timeline_png
from .results import Result
from .trace import make_trace

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
    import pyarrow.parquet as pq  # noqa: PLC0415
    tmp = path.with_name(path.name + ".tmp")
    schema = pa.Schema.from_pandas(make_trace([]), preserve_index=False)
    if path.suffix == ".parquet":
        with pq.ParquetWriter(tmp, schema) as writer:
            for table in result.repeated.arrow_chunks(schema, rows_per_group):
                writer.write_table(table)
    else:
        import pyarrow.csv as pcsv  # noqa: PLC0415
        with pcsv.CSVWriter(tmp, schema) as writer:
            for table in result.repeated.arrow_chunks(schema, rows_per_group):
                writer.write_table(table)
    tmp.replace(path)
    return path


def write_json(obj: Any, path: Path) -> Path:
    """Strict JSON (NaN and infinities become null), written whole or not at all."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_finite(obj), indent=2, sort_keys=True, default=_jsonable, allow_nan=False) + "\n")
    tmp.replace(path)
    return path


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
    """A measured run (`mgpusim.runner.RunResult`) as `validate --measured` reads it: trace,
    frames, summary.json with the configuration, machine.json."""
    out.mkdir(parents=True, exist_ok=True)
    write_table(result.trace, out / f"trace.{trace_format}")
    write_table(result.frames, out / f"frames.{trace_format}")
    write_json({**result.summary, "config": result.config}, out / "summary.json")
    write_json(result.machine, out / "machine.json")
    return out


def write_result(result: Result, out: Path, trace_format: str = "parquet", title: str = "") -> dict[str, Path]:
    """summary.json, trace + frames tables, timeline.png and trace.perfetto.json in `out`."""
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "summary": write_json({**result.summary, "config": result.config}, out / "summary.json"),
        "trace": write_trace(result, out / f"trace.{trace_format}"),
        "frames": write_table(result.frames, out / f"frames.{trace_format}"),
        "links": write_table(result.links, out / f"links.{trace_format}"),
    }
    if len(result.trace):
        files["timeline"] = timeline_png(result.trace, out / "timeline.png", result.links, title)
        files["perfetto"] = write_json(chrome_trace(result.trace, result.links, title), out / "trace.perfetto.json")
    return files
