"""Writing a run's results to a folder (the edge of the program: files live here only)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from .perfetto import chrome_trace
from .plot import timeline_png
from .results import Result

SUMMARY_KEYS = ("frame_time_ms", "fps", "latency_ms", "utilization")


def write_table(df: pd.DataFrame, path: Path) -> Path:
    """CSV or Parquet by the file's extension."""
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False)
    return path


def write_json(obj: Any, path: Path) -> Path:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_jsonable) + "\n")
    tmp.replace(path)
    return path


def _jsonable(value: Any) -> Any:
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, (set, tuple)):
        return list(value)
    return str(value)


def write_result(result: Result, out: Path, trace_format: str = "parquet", title: str = "") -> dict[str, Path]:
    """summary.json, trace + frames tables, timeline.png and trace.perfetto.json in `out`."""
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "summary": write_json({**result.summary, "config": result.config}, out / "summary.json"),
        "trace": write_table(result.trace, out / f"trace.{trace_format}"),
        "frames": write_table(result.frames, out / f"frames.{trace_format}"),
        "links": write_table(result.links, out / f"links.{trace_format}"),
    }
    if len(result.trace):
        files["timeline"] = timeline_png(result.trace, out / "timeline.png", result.links, title)
        files["perfetto"] = write_json(chrome_trace(result.trace, result.links, title), out / "trace.perfetto.json")
    return files
