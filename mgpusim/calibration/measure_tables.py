"""Checks on `mgpusim measure` tables before calibration: a table the fit cannot use is
refused with one line naming the file, the column and the first bad row, so the solver only
ever sees finite, positive durations and the parameters each pass's work terms need."""
from __future__ import annotations

import pandas as pd

from mgpusim.model.errors import InputError
from mgpusim.model.geometry import MESH_OPTIONS, PASS_OPTIONS
from mgpusim.model.limits import MAX_TASK_NS, MAX_WORK
from mgpusim.model.toml_checks import did_you_mean
from mgpusim.validation.measured_check import number_column, unknown_names

#: The measure library's passes and the columns each row of one needs (its parameters).
MEASURED_PASSES: dict[str, tuple[str, ...]] = {
    "fragment_loop": ("width", "height", "iterations"),
    "mesh": ("width", "height", "triangles"),
    "composite_sort_first": ("width", "height", "inputs"),
    "composite_sort_last": ("width", "height", "inputs"),
    "present": ("width", "height"),
    "filter": ("width", "height", "iterations", "inputs"),
    "particle_update": ("particles",),
    "particle_render": ("width", "height", "particles"),
    "copy_d2h": ("bytes", "queue"),
    "copy_h2d": ("bytes", "queue"),
    "copy_d2d": ("bytes", "queue"),
    "host_copy": ("bytes", "threads"),
    "overlap": ("pair", "alone_a_ns", "alone_b_ns"),
}
#: Numeric columns: finite, in [0, MAX_WORK] wherever a row has them (durations in
#: (0, MAX_TASK_NS]: the bounds of the model's own inputs).
NUMERIC_COLUMNS = ("width", "height", "iterations", "triangles", "inputs", "particles", "bytes",
                   "threads", "gpus", "lp_threads", "cpu_ns", "alone_a_ns", "alone_b_ns")

#: Every other column the measure library and its probes write: what a row identifies (the
#: device, GPU, pass and repetition), where a copy or mesh ran, the mesh drawn (`shape`,
#: `cull`), the overlap probe's pair, and the file a row came from once tables are read
#: together (`source`).
RECORD_COLUMNS = ("device", "gpu", "pass", "repetition", "duration_ns", "queue", "place", "pair",
                  "queue_a", "queue_b", "copy", "graphics", "efficiency", "missing", "source",
                  *MESH_OPTIONS)
#: The columns a measure table may have: a column beyond these is a renamed or mistyped one,
#: whose values the fit would otherwise ignore without a word.
KNOWN_COLUMNS = tuple(dict.fromkeys((*RECORD_COLUMNS, *NUMERIC_COLUMNS,
                                     *(c for needs in MEASURED_PASSES.values() for c in needs))))


def check_measure_table(df: pd.DataFrame, file: str) -> pd.DataFrame:
    """Refuse a table with no rows, no pass or duration column, unknown passes, missing
    parameters, or non-finite or non-positive numbers; return it with numeric columns as float."""
    for col in ("pass", "duration_ns"):
        if col not in df.columns:
            raise InputError(f"not a measure table (no {col!r} column; columns: "
                             f"{', '.join(map(str, df.columns)) or 'none'})", file=file)
    if df.empty:
        raise InputError("the table has a header but no rows", file=file)
    strange = [str(c) for c in df.columns if c not in KNOWN_COLUMNS]
    if strange:
        raise InputError(f"unknown column {strange[0]!r}{did_you_mean(strange[0], KNOWN_COLUMNS)} "
                         f"(a measure table's columns: {', '.join(KNOWN_COLUMNS)})", file=file,
                         field=strange[0])
    for key, names in PASS_OPTIONS["mesh"].items():
        odd = unknown_names(df[key].dropna(), names) if key in df.columns else []
        if odd:
            raise InputError(f"unknown {key} {odd[0]!r}{did_you_mean(odd[0], names)} (a mesh's "
                             f"{key}: {', '.join(names)})", file=file, field=key)
    unknown = unknown_names(df["pass"], MEASURED_PASSES)
    if unknown:
        raise InputError(f"unknown pass {unknown[0]!r}{did_you_mean(unknown[0], MEASURED_PASSES)} "
                         f"(the measure library has {', '.join(MEASURED_PASSES)})", file=file,
                         field="pass")
    out = df.copy()
    out["duration_ns"] = number_column(df["duration_ns"], file, "duration_ns", above=0,
                                       maximum=MAX_TASK_NS)
    for col in NUMERIC_COLUMNS:
        if col in out.columns:
            out[col] = number_column(df[col], file, col, minimum=0, maximum=MAX_WORK,
                                     rows=df[col].notna())
    overlap = out["pass"] == "overlap"
    for col in ("alone_a_ns", "alone_b_ns"):
        if overlap.any() and col in out.columns:
            number_column(df.loc[overlap, col], file, col, above=0, maximum=MAX_TASK_NS)
    for kind, needs in MEASURED_PASSES.items():
        rows = out["pass"] == kind
        for col in needs:
            if rows.any() and (col not in out.columns or out.loc[rows, col].isna().any()):
                raise InputError(f"{kind} rows need a {col!r} value (the fit's work terms use it)",
                                 file=file, field=col)
    return out
