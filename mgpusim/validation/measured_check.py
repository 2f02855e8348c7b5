"""Checks on measured data read back from disk (measured runs, measure tables), so that a
broken or mismatched file is one InputError naming it and the column or field, never a
pandas traceback or a comparison of unlike runs.

`read_table` and `read_json_object` are the only functions here that touch files (on disk, or in
a packed folder of runs: :mod:`mgpusim.measure.run_archive`); the checks take what they read.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterable, Mapping, cast

import numpy as np
import pandas as pd

from mgpusim.io import table_files
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.profile import CalibratedOn
from mgpusim.results.trace import TRACE_COLUMNS
from mgpusim.schedules import SCHEDULES, ensure_loaded
from mgpusim.schedules.program import build_program, run_config

#: How a key missing on one side shows in a mismatch message.
_ABSENT = "no value"
#: Integer columns of a measured trace.
TRACE_INT_COLUMNS = ("frame", "start_ns", "end_ns", "bytes")
#: Recorded keys a measured run may differ in from its experiment: its name, file and
#: profile's name (a study validates a run with other files and a calibrated profile), the
#: runner's mark, and the model's what-ifs (a measured run ran on the machine it ran on).
UNCOMPARED_KEYS = ("experiment", "file", "profile", "measured", "profile_overrides")
#: The keys whose difference a message names first (what a reader recognises a run by).
FIRST_KEYS = ("schedule", "gpus", "width", "height", "host_copy", "inputs")


def read_table(path: Path, ends_whole: bool = False) -> pd.DataFrame:
    """A CSV or Parquet table (by extension), on disk or in a packed runs folder; unreadable,
    empty or corrupt files are one InputError naming the file (:mod:`mgpusim.io.table_files`).
    `ends_whole`: a table this tool wrote (a measured trace, a measure table), which ends
    with a newline unless it was cut short."""
    return run_archive.read_table(path, ends_whole=ends_whole)


def read_json_object(path: Path) -> dict[str, Any]:
    """A JSON file holding one object (summary.json, machine.json), on disk or in a packed
    runs folder."""
    return table_files.json_object(run_archive.read_json(path), str(path))


def check_trace(df: pd.DataFrame, file: str) -> pd.DataFrame:
    """A measured trace with the trace columns, integer times (end >= start), frames >= 0;
    returned with int64 times."""
    missing = [c for c in TRACE_COLUMNS if c not in df.columns]
    if missing:
        raise InputError(f"not a trace: missing column(s) {', '.join(missing)} (a trace has "
                         f"{', '.join(TRACE_COLUMNS)})", file=file)
    if df.empty:
        raise InputError("the trace has no rows", file=file)
    out = df.copy()
    for col in TRACE_INT_COLUMNS:
        out[col] = integer_column(df[col], file, col, minimum=0)
    bad = np.flatnonzero(out["end_ns"].to_numpy() < out["start_ns"].to_numpy())
    if len(bad):
        i = int(bad[0])
        more = f" and {len(bad) - 1} other row(s)" if len(bad) > 1 else ""
        raise InputError(f"end_ns < start_ns in row {i} ({out['end_ns'].iat[i]} < "
                         f"{out['start_ns'].iat[i]}){more}", file=file, field="end_ns")
    for col in ("device", "engine", "step", "task", "waits_for"):
        out[col] = out[col].fillna("").astype(str)
    return out


def integer_column(col: pd.Series, file: str, name: str, minimum: int | None = None) -> pd.Series:
    """`col` as int64: every value a finite whole number in [minimum, int64]."""
    values = pd.to_numeric(col, errors="coerce")
    as_float = values.astype(float)
    # a Series (numpy's stubs type a ufunc of a Series as an ndarray)
    ok = cast(pd.Series, np.isfinite(as_float) & (as_float == np.floor(as_float)) & (as_float.abs() < 2.0 ** 63))
    if minimum is not None:
        ok &= as_float >= minimum
    if not ok.all():
        i = int(np.flatnonzero(~ok.to_numpy())[0])
        need = f"whole numbers >= {minimum}" if minimum is not None else "whole numbers"
        raise InputError(f"expected {need}, got {_short(col.iat[i])} in row {i}", file=file,
                         field=name)
    return values.astype("int64")


def number_column(col: pd.Series, file: str, name: str, *, minimum: float | None = None,
                  above: float | None = None, maximum: float | None = None,
                  rows: pd.Series | None = None) -> pd.Series:
    """`col` as float: finite numbers (in the range) on `rows` (all rows by default)."""
    values = pd.to_numeric(col, errors="coerce").astype(float)
    ok = cast(pd.Series, np.isfinite(values))  # a Series (numpy's stubs say ndarray)
    if minimum is not None:
        ok &= values >= minimum
    if above is not None:
        ok &= values > above
    if maximum is not None:
        ok &= values <= maximum
    if rows is not None:
        ok |= ~rows
    if not ok.all():
        i = int(np.flatnonzero(~ok.to_numpy())[0])
        bound = f" > {above:g}" if above is not None else f" >= {minimum:g}" if minimum is not None else ""
        bound += f" and <= {maximum:g}" if maximum is not None else ""
        raise InputError(f"expected finite numbers{bound}, got {_short(col.iat[i])} in row {i}",
                         file=file, field=name)
    return values


def check_recorded_config(config: dict[str, Any], exp: Any, file: str) -> None:
    """Refuse a measured run whose recorded configuration differs from the experiment's in any
    key both record (one line: the first difference in full, the other differing keys named).
    What may differ: names and paths (`UNCOMPARED_KEYS`), frame counts (not recorded here), and
    what only one side records (runs saved before a key was recorded, runner-only facts such
    as host_threads); schedule options a run predates are compared only off their default."""
    want = json.loads(json.dumps(run_config(exp, build_program(exp)), default=_as_json))  # as recorded
    recorded = config.get("inputs")
    if isinstance(recorded, dict) and isinstance(want.get("inputs"), dict):
        _drop_newer_defaults(config, want["inputs"], exp.schedule.name)
        for part in set(want["inputs"]) - set(recorded):  # a part recorded only by newer runs
            want["inputs"].pop(part)
    keys = sorted(set(config) & set(want) - set(UNCOMPARED_KEYS),
                  key=lambda k: (FIRST_KEYS.index(k) if k in FIRST_KEYS else len(FIRST_KEYS), k))
    found = [d for key in keys for d in differences(config[key], want[key], f"config.{key}")]
    if found:
        path, got, expected = found[0]
        others = [p for p, _, _ in found[1:]]
        more = (f"; {len(others)} other key(s) differ too: {', '.join(others[:6])}"
                f"{', ...' if len(others) > 6 else ''}") if others else ""
        raise InputError(f"the measured run has {_short(got)} but the experiment has "
                         f"{_short(expected)}{more}: this run is of another configuration; "
                         "measure it again or --set the experiment to match", file=file, field=path)


def _drop_newer_defaults(config: dict[str, Any], inputs: dict[str, Any], schedule: str) -> None:
    """Leave out of the comparison the schedule options that a measured run does not record
    and that the experiment leaves at their default: options added after the run was recorded,
    which change nothing at their default."""
    recorded = config.get("inputs", {}).get("schedule") if isinstance(config.get("inputs"), dict) else None
    if not isinstance(recorded, dict):
        return
    ensure_loaded()
    options = SCHEDULES[schedule].options if schedule in SCHEDULES else {}
    for key, option in options.items():
        default = json.loads(json.dumps(option.default, default=list))  # as inputs record it
        if key not in recorded and inputs["schedule"].get(key) == default:
            inputs["schedule"].pop(key, None)


def machine_of(record: dict[str, Any]) -> CalibratedOn | None:
    """The machine a run's `machine.json` describes, in a profile's terms (its CPU model and
    usable CPUs, its first GPU's device and driver); None for a record without them."""
    gpus = record.get("gpus")
    gpu = gpus[0] if isinstance(gpus, list) and gpus and isinstance(gpus[0], dict) else None
    cpus = record.get("affinity_cpus") or record.get("cpu_count")
    if gpu is None or not isinstance(record.get("cpu"), str) or not isinstance(cpus, int):
        return None
    driver = f"{gpu.get('driver', '')} {gpu.get('driver_info', '')}".strip()
    return CalibratedOn(record["cpu"], cpus, str(gpu.get("device", "")), driver)


def check_physical_gpus(machine: dict[str, Any], exp: Any, file: str) -> None:
    """Refuse to compare a run whose simulated GPUs shared real GPUs differently from the
    profile (`gpus.physical`): two VkDevices on one GPU slow each other down, which the model
    shows only when the profile says they share it. Lavapipe GPUs share the CPU instead
    (host.gpus_share_cpu); runs recorded before `physical_index` was are not checked."""
    profile = exp.profile
    gpus = machine.get("gpus")
    if profile.host.gpus_share_cpu or not isinstance(gpus, list):
        return
    ran = [g.get("physical_index") if isinstance(g, dict) else None for g in gpus]
    n = min(len(ran), len(profile.gpus))
    if any(not isinstance(p, int) for p in ran[:n]):
        return
    for j in range(n):
        for i in range(j):
            together, modelled = ran[i] == ran[j], profile.physical_of(i) == profile.physical_of(j)
            if together != modelled:
                said = "gives them GPUs of their own" if together else "puts them on one"
                raise InputError(f"simulated GPUs {i} and {j} ran on "
                                 f"{'one physical GPU' if together else 'different physical GPUs'}, "
                                 f"but the profile {said}: give the profile's GPUs `physical` as "
                                 "they ran (e.g. --set profile.gpus.0.physical=0 with "
                                 "profile.gpu_count)", file=file, field=f"gpus[{j}].physical")


def differences(got: Any, want: Any, path: str, limit: int = 1000) -> list[tuple[str, Any, Any]]:
    """(dotted path, got, want) of every place (up to `limit`) two JSON-shaped values differ:
    a key on one side only, a list of another length, a value unlike the other."""
    if isinstance(got, dict) and isinstance(want, dict):
        out: list[tuple[str, Any, Any]] = []
        for key in sorted(set(got) | set(want), key=str):
            out += differences(got.get(key, _ABSENT), want.get(key, _ABSENT), f"{path}.{key}", limit - len(out))
            if len(out) >= limit:
                break
        return out
    if isinstance(got, list) and isinstance(want, list):
        if len(got) != len(want):
            return [(path, f"{len(got)} entries", f"{len(want)}")]
        out = []
        for i, (g, w) in enumerate(zip(got, want)):
            out += differences(g, w, f"{path}[{i}]", limit - len(out))
            if len(out) >= limit:
                break
        return out
    return [] if _same(got, want) else [(path, got, want)]


def _as_json(value: Any) -> Any:
    return dict(value) if isinstance(value, Mapping) else list(value)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=0)
    return a == b


def unknown_names(values: Iterable[Any], known: Iterable[str]) -> list[str]:
    """The distinct values not in `known`, in first-seen order."""
    known = set(known)
    return list(dict.fromkeys(str(v) for v in values if str(v) not in known))


def _short(value: Any, limit: int = 80) -> str:
    text = str(value).replace("\n", " ")
    return text if len(text) <= limit else text[:limit] + "..."
