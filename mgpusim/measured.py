"""Reading a saved measured run (from `mgpusim run`, a study, or a committed data folder).

A measured folder holds `trace.parquet` or `trace.csv` in the trace schema and, usually,
`summary.json` with the configuration it was measured with; that configuration must match the
experiment it is compared with, or the comparison would report the difference as model error.
"""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from .errors import InputError
from .experiment import Experiment

TRACE_FILES = ("trace.parquet", "trace.csv")


def read_measured(folder: Path, exp: Experiment) -> pd.DataFrame:
    """A saved measured trace; its recorded configuration must match the experiment's."""
    for name in TRACE_FILES:
        path = folder / name
        if path.is_file():
            trace = (pd.read_parquet(path) if path.suffix == ".parquet"
                     else pd.read_csv(path, keep_default_na=False))
            break
    else:
        raise InputError("no trace.parquet or trace.csv in the measured folder", file=str(folder))
    summary = folder / "summary.json"
    if summary.is_file():
        config = json.loads(summary.read_text()).get("config", {})
        for key, want in (("schedule", exp.schedule.name), ("gpus", exp.schedule.gpus),
                          ("width", exp.scene.width), ("height", exp.scene.height)):
            if key in config and config[key] != want:
                raise InputError(f"measured run has {key}={config[key]!r} but the experiment has "
                                 f"{want!r}", file=str(summary), field=f"config.{key}")
    return trace.astype({"start_ns": "int64", "end_ns": "int64", "frame": "int64"})
