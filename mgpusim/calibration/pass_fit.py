"""Turn `mgpusim measure` tables into cost-model coefficients and a hardware profile.

- pass kinds: fixed_ns + ns_per_<term> * work, the work terms of :mod:`mgpusim.model.costs`;
- copies: per path and queue family, fixed_ns + bytes / bandwidth;
- host copies: throughput against thread count, min(threads * per_thread, memory bandwidth);
- lavapipe: each simulated GPU's passes are CPU work on the host's cores (`host.gpus_share_cpu`),
  with `cpu_threads` per GPU, so GPUs and host threads running at once slow each other down.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from mgpusim.calibration.fit import Fit, fit_nonnegative
from mgpusim.calibration.measure_tables import check_measure_table
from mgpusim.calibration.overlap_fit import fit_overlap
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import MESH_OPTIONS, MESH_PLACE, mesh_placement
from mgpusim.model.scene import PassSpec
from mgpusim.model.work_terms import (
    PLACED_TERMS,
    QUEUE_THREAD_TERMS,
    REFERENCE_KINDS,
    UNPRICED_OK,
    WORK_TERMS,
)
from mgpusim.model.work_terms import pass_work as pass_work_placed
from mgpusim.validation.measured_check import read_json_object, read_table

#: Every pass kind of the cost model that is measured and fitted: all but those known only by a
#: reference time ("timed", "captured").
PASS_KINDS = tuple(kind for kind in WORK_TERMS if kind not in REFERENCE_KINDS)
COPY_PASSES = {"copy_d2h": "d2h", "copy_h2d": "h2d", "copy_d2d": "d2d"}


#: Pass parameters that enter the work terms, and all columns that identify one measured
#: configuration of a pass.
WORK_PARAMS = ("iterations", "triangles", "inputs", "particles")
PARAM_COLUMNS = ("width", "height") + WORK_PARAMS + tuple(MESH_PLACE) + tuple(MESH_OPTIONS)


@dataclass
class Calibration:
    pass_fits: dict[str, Fit] = field(default_factory=dict)
    #: lavapipe: cores each pass kind keeps busy, with the per-size values (see fit_cores)
    cores: dict[str, tuple[float, list[float]]] = field(default_factory=dict)
    #: lavapipe: how each kind's cores were measured, where not by CPU time
    cores_method: dict[str, str] = field(default_factory=dict)
    #: lavapipe: cores of a kind's queue-thread terms where pairs told them from the rest's
    #: (`cores` then holds for the rest), with the per-size slowdowns they were fitted on
    term_cores: dict[str, dict[str, float]] = field(default_factory=dict)
    #: lavapipe: per pass kind, CPU time of a submission outside the pass (the fit's intercept)
    submission_cpu_ns: dict[str, float] = field(default_factory=dict)
    copy_fits: dict[tuple[str, str], Fit] = field(default_factory=dict)
    #: host copies: GB/s and ns (floats), and the throughput per thread count (a table)
    host: dict[str, Any] = field(default_factory=dict)
    #: overlap efficiency per queue pair: (median over sizes, each size's) (calibrate/overlap.py)
    overlap: dict[str, tuple[float, list[float]]] = field(default_factory=dict)
    machine: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def read_measurements(paths: list[Path]) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Concatenate measure tables (CSV or Parquet); return them and the first machine record."""
    frames: list[pd.DataFrame] = []
    machine: dict[str, Any] = {}
    for path in paths:
        df = check_measure_table(read_table(path, ends_whole=True), str(path))
        df["source"] = path.name
        frames.append(df)
        record = path.with_name(path.name + ".machine.json")
        if not machine and run_archive.is_file(record):  # on disk, or in its packed folder
            machine = read_json_object(record)
    return pd.concat(frames, ignore_index=True), machine


def pass_work(row: pd.Series) -> dict[str, float]:
    """Work terms of one measured pass, as the schedules would give them. A mesh row of a
    table that says where it drew (the placement columns) has the placed terms too; an older
    table's rows keep the triangles-and-pixels model."""
    kind = row["pass"]
    pixels = float(row.get("width", 0) or 0) * float(row.get("height", 0) or 0)
    params = {k: float(row[k]) for k in WORK_PARAMS if k in row and pd.notna(row[k])}
    if kind == "composite_sort_last":
        pixels *= params.get("inputs", 1)  # one full-screen quad per input
    options = {k: str(row[k]) for k in MESH_OPTIONS if kind == "mesh" and k in row and pd.notna(row[k])}
    spec = PassSpec(kind, kind, params, options=options)
    if kind == "mesh" and all(k in row and pd.notna(row[k]) for k in MESH_PLACE):
        place = mesh_placement(cast(dict[str, Any], row.to_dict()))
        view = place.mesh_view(int(params["triangles"]), spec.option("shape"), spec.option("cull"))
        assert view.count is not None  # mesh_view counts the triangles it draws
        return pass_work_placed(spec, place.pixels, view.count / view.triangles, place)
    return WORK_TERMS[kind](spec, pixels, 1.0)


def fit_passes(df: pd.DataFrame, cal: Calibration) -> None:
    """One fit per pass kind, on single-GPU rows at the GPU's full thread count (rows on fewer
    lavapipe threads are another GPU's)."""
    solo = df[_solo(df) & _all_threads(df)]
    for kind in PASS_KINDS:
        rows = solo[solo["pass"] == kind]
        if rows.empty:
            continue
        works = [pass_work(r) for _, r in rows.iterrows()]
        fit = _fit_kind(kind, works, rows["duration_ns"].to_numpy())
        cal.pass_fits[kind] = fit
        cal.warnings.extend(fit.warnings)


def _fit_kind(kind: str, works: list[dict[str, float]], durations: np.ndarray) -> Fit:
    """Fit one kind's coefficients. A term that a profile may lack (:data:`UNPRICED_OK`: the
    particle draw's `particle_pixel`) is left out where the table cannot tell it from the others
    (one particle count, or one view size): the kind keeps its older model rather than an
    arbitrary split of the time. The mesh's placed terms stay (the studies fit them on tables of
    several view sizes together; a table that cannot tell them apart says so in its warning)."""
    terms = sorted({t for w in works for t in w})
    fit = _fit_terms(kind, works, durations, terms)
    optional = [t for t in terms if t in UNPRICED_OK.get(kind, ()) and t not in PLACED_TERMS.get(kind, ())]
    if optional and any("cannot tell" in w for w in fit.warnings):
        kept = [t for t in terms if t not in optional]
        reduced = _fit_terms(kind, works, durations, kept)
        reduced.warnings.append(f"{kind}: the measurements cannot tell {optional} from the other terms; "
                                "left out (the older model); sweep more sizes to price them")
        return reduced
    return fit


def _fit_terms(kind: str, works: list[dict[str, float]], durations: np.ndarray, terms: list[str]) -> Fit:
    X = np.array([[1.0] + [w.get(t, 0.0) for t in terms] for w in works])
    return fit_nonnegative(X, durations, ["fixed_ns"] + [f"ns_per_{t}" for t in terms], kind)


def fit_cores(df: pd.DataFrame, cal: Calibration) -> None:
    """lavapipe: per pass kind, the cores it keeps busy while it runs, which is what decides how
    much passes running at once slow each other. Measured two ways:

    - where the table has the kind on two GPUs at once (`gpus` = 2) and alone at the same
      sizes: the median over sizes of (time together / time alone). Two passes that each keep
      c of the two cores busy take c times as long together (each gets one core), so that
      slowdown *is* c as the model uses it. Why it wins: a lavapipe mesh pass keeps ~1.2 cores
      busy by CPU time, but two at once take 1.2-1.5x as long (their binning competes for the
      caches and memory, not only the cores), and with 1.2 the model made every multi-GPU mesh
      run 5-20 % too fast;
    - else the slope of the process's CPU time (`cpu_ns`, all threads) against the pass's
      duration over the sizes measured (medians per size; the intercept is what a submission
      costs outside the pass's timestamps, 0.1-0.4 ms).

    Either is at least 1 (the queue thread runs the pass) and at most the GPU's threads."""
    if "cpu_ns" not in df.columns or "lp_threads" not in df.columns:
        return  # only lavapipe GPUs (lp_threads set) run their passes on the host's cores
    rows = df[_solo(df) & _all_threads(df) & df["cpu_ns"].notna() & df["lp_threads"].notna()]
    for kind in PASS_KINDS:
        mine = rows[rows["pass"] == kind]
        keys = [c for c in PARAM_COLUMNS if c in mine.columns and mine[c].notna().all()]
        if mine.empty or not keys:
            continue
        most = float(mine["lp_threads"].max())
        pair = _pair_slowdowns(df, kind, keys)
        if pair is not None:
            cal.cores[kind] = (float(np.clip(pair.median(), 1.0, most)), [float(r) for r in pair])
            cal.cores_method[kind] = "slowdown of two at once"
            _fit_term_cores(cal, kind, pair, keys, most)
        sizes = mine.groupby(keys)[["duration_ns", "cpu_ns"]].median()
        if sizes["duration_ns"].nunique() < 2:
            if pair is None:
                cal.warnings.append(f"{kind}: CPU time measured at one size only, cores not fitted")
            continue
        X = np.column_stack([sizes["duration_ns"], np.ones(len(sizes))])
        (slope, overhead), *_ = np.linalg.lstsq(X, sizes["cpu_ns"].to_numpy(dtype=float), rcond=None)
        cal.submission_cpu_ns[kind] = float(overhead)
        if pair is None:
            per_size = (sizes["cpu_ns"] - overhead) / sizes["duration_ns"]
            cal.cores[kind] = (float(np.clip(slope, 1.0, most)), [float(r) for r in per_size])


def _fit_term_cores(cal: Calibration, kind: str, pair: pd.Series, keys: list[str],
                    most: float) -> None:
    """Where the pairs' sizes mix the kind's queue-thread terms (QUEUE_THREAD_TERMS) and its
    other work in different shares (a mesh whose triangles are mostly culled beside one whose
    triangles are all rasterized), fit the cores of each part: two passes that each keep c
    cores busy take c times as long together, and a pass's c is its parts' cores weighted by
    their time, so slowdown x time = c_thread x its queue-thread time + c_rest x the rest's,
    linear in the two (least squares, each kept in [1, the GPU's threads]). Where the cost fit
    could not tell its terms apart (our torus alone: every triangle it draws is rasterized, so
    its triangles and rasterized triangles go together) or the shares do not differ enough
    (less than 0.2 between the pairs' extremes), the kind keeps one `cores`."""
    fit, terms = cal.pass_fits.get(kind), QUEUE_THREAD_TERMS.get(kind, ())
    if fit is None or not terms or any("cannot tell" in w for w in fit.warnings):
        return
    coef = dict(zip(fit.names, fit.coef))
    thread, total = [], []
    for size in pair.index:
        row = pd.Series({"pass": kind, **dict(zip(keys, size if isinstance(size, tuple) else (size,)))})
        work = pass_work(row)
        parts = {t: coef.get(f"ns_per_{t}", 0.0) * a for t, a in work.items()}
        thread.append(sum(v for t, v in parts.items() if t in terms))
        total.append(coef.get("fixed_ns", 0.0) + sum(parts.values()))
    a, t = np.array(thread), np.array(total)
    share = a / t
    if share.max() - share.min() < 0.2:
        return
    X, y = np.column_stack([a, t - a]), pair.to_numpy(dtype=float) * t
    (c_thread, c_rest), *_ = np.linalg.lstsq(X, y, rcond=None)
    c_thread = float(np.clip(c_thread, 1.0, most))
    c_rest = float(np.clip(np.sum((y - c_thread * a) * (t - a)) / np.sum((t - a) ** 2), 1.0, most))
    cal.term_cores[kind] = {term: c_thread for term in terms}
    cal.cores[kind] = (c_rest, cal.cores[kind][1])


def _pair_slowdowns(df: pd.DataFrame, kind: str, keys: list[str]) -> pd.Series | None:
    """Per size measured both ways, the median time of `kind` on two GPUs at once over its
    median time alone (None where no size was)."""
    if "gpus" not in df.columns:
        return None
    mine = df[(df["pass"] == kind) & _all_threads(df)]
    alone = mine[mine["gpus"].fillna(1) <= 1].groupby(keys)["duration_ns"].median()
    both = mine[mine["gpus"] == 2].groupby(keys)["duration_ns"].median()
    ratio = (both / alone).dropna()
    return ratio if len(ratio) else None


def fit_copies(df: pd.DataFrame, cal: Calibration) -> None:
    for name, path in COPY_PASSES.items():
        rows = df[(df["pass"] == name) & _solo(df)]
        if rows.empty:
            continue
        for queue, group in rows.groupby("queue"):
            fit = fit_copy_line(group, f"{name} on {queue}")
            cal.copy_fits[(path, str(queue))] = fit
            cal.warnings.extend(fit.warnings)


def fit_host_copies(df: pd.DataFrame, cal: Calibration) -> None:
    """Throughput per thread count; per-thread speed from 1 thread, the plateau from the most."""
    rows = df[df["pass"] == "host_copy"]
    if rows.empty:
        return
    throughput: dict[int, float] = {}
    fixed: list[float] = []
    for threads, group in rows.groupby("threads"):
        fit = fit_copy_line(group, f"host_copy x{threads}")
        cal.warnings.extend(fit.warnings)
        throughput[int(cast(int, threads))] = 1.0 / fit.coef[1]
        fixed.append(fit.coef[0])
    one = throughput.get(1, min(throughput.values()))
    most = max(throughput)
    plateau = throughput[most]
    cal.host = {"memcpy_thread_gbps": one, "host_copy_fixed_ns": float(np.median(fixed)),
                "throughput_by_threads_gbps": {str(k): v for k, v in sorted(throughput.items())}}
    if plateau >= 0.9 * most * one:
        cal.warnings.append(f"host copies still scale at {most} threads: memory bandwidth is at least "
                            f"{plateau:.1f} GB/s (not saturated in the measured range)")
    cal.host["memory_bandwidth_gbps"] = max(plateau, one)


#: The share of its largest copy's time that a fitted per-byte cost must explain to count as
#: resolved: below it the bytes made no measurable difference (noise, or a fixed cost that
#: swamps them) and 1 / slope would be an arbitrary, possibly astronomical rate.
RESOLVED_SHARE = 0.01


def fit_copy_line(group: pd.DataFrame, what: str) -> Fit:
    """A copy's time as fixed_ns + ns_per_byte x bytes over the rows of `group`, the per-byte
    cost as :func:`per_byte_ns` takes it (its warning among the fit's): every copy fit's one
    rule (device copies, host copies, the NVIDIA recipe's host copy)."""
    X = np.column_stack([np.ones(len(group)), group["bytes"].to_numpy(dtype=float)])
    fit = fit_nonnegative(X, group["duration_ns"].to_numpy(dtype=float), ["fixed_ns", "ns_per_byte"], what)
    fit.coef[1] = per_byte_ns(fit.coef[1], group, what, fit.warnings)
    return fit


def per_byte_ns(ns_per_byte: float, group: pd.DataFrame, what: str, warnings: list[str]) -> float:
    """A copy's fitted ns per byte where the bytes explain at least RESOLVED_SHARE of its
    largest copy's time; else the fastest whole copy measured (fixed cost included), whose
    rate is a finite lower bound, with a warning."""
    # pandas-stubs: .loc takes any label, and idxmax gives one typed Hashable
    largest = group.loc[group["bytes"].idxmax()]  # type: ignore[call-overload]
    if ns_per_byte * float(largest["bytes"]) >= RESOLVED_SHARE * float(largest["duration_ns"]):
        return float(ns_per_byte)
    fastest = float((group["duration_ns"] / group["bytes"]).min())
    warnings.append(f"{what}: no per-byte cost resolved above the noise; the rate is the "
                    f"fastest whole copy measured, {1 / fastest:.1f} GB/s (a lower bound)")
    return fastest


def _solo(df: pd.DataFrame) -> pd.Series:
    """Rows measured with one simulated GPU at a time."""
    if "gpus" in df.columns:
        return df["gpus"].fillna(1) <= 1
    return ~df["source"].str.contains("gpus")  # tables written before the column existed


def _all_threads(df: pd.DataFrame) -> pd.Series:
    """Rows of real GPUs, or of lavapipe GPUs on the most threads measured for their pass."""
    if "lp_threads" not in df.columns:
        return pd.Series(True, index=df.index)
    most = df.groupby("pass")["lp_threads"].transform("max")
    return df["lp_threads"].isna() | (df["lp_threads"] == most)


def calibrate(df: pd.DataFrame, machine: dict[str, Any]) -> Calibration:
    cal = Calibration(machine=machine)
    fit_passes(df, cal)
    fit_cores(df, cal)
    fit_copies(df, cal)
    fit_host_copies(df, cal)
    cal.overlap, warnings = fit_overlap(df)
    cal.warnings.extend(warnings)
    if not (cal.pass_fits or cal.copy_fits or cal.host or cal.overlap):
        raise InputError("nothing to fit: no single-GPU pass, copy or host-copy rows (at the "
                         "GPU's full thread count) in " + ", ".join(sorted(set(map(str, df["source"])))))
    return cal
