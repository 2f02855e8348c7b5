"""A study's calibration, step by step: microbenchmark tables, then measured runs.

The one place that says how a profile is fitted for a machine. The steps a study's recipe
(:class:`mgpusim.studies.study_file.Recipe`) switches on, in order:
1. the pass, copy and host-copy tables (`mgpusim measure` output) fitted onto a base profile:
   a lavapipe skeleton made from the tables' machine record, or the study profile's own
   structure (queues, links, memory) for real GPUs; where the recipe asks (`host_pcie`), the
   host side of PCIe per direction from the copy rows with the most GPUs copying at once;
2. host copy on the host's memcpy threads as fixed + bytes / bandwidth, from a table measured
   with that many threads;
3. cost kinds and host keys copied from another profile (a machine with no multi-GPU runs of
   its own borrowing the runner-form fits of one of the same chip);
4. pass costs refitted on the calibration runs' own rows (what the runner records), the
   kinds only multi-GPU runs have scaled to their instances that ran alone on the cores, and
   the copies' fixed cost from the runs' copies alone on the cores;
5. the queues' idle gap between tasks (1-GPU runs) and the host-copy thread's wake latency;
6. a grid search of the host effects on the runs' frame-time error.
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from mgpusim.calibration.busy_wake_fit import fit_busy_wake
from mgpusim.calibration.pass_fit import COPY_PASSES, calibrate, fit_copy_line, read_measurements
from mgpusim.calibration.profile_out import apply, lavapipe_base, report
from mgpusim.calibration.run_fit import (
    Run,
    copy_wake_after_dispatch,
    fit_alone_scales,
    fit_copy_setup,
    fit_host_copy_wake,
    fit_host_effects,
    fit_passes_from_runs,
    fit_task_gap,
    with_alone_scales,
    with_pass_fits,
)
from mgpusim.model.profile import BUSY_WAKE_WINDOW_NS
from mgpusim.model.toml_checks import read_toml
from mgpusim.model.work_terms import PLACED_TERMS


def profile_from_tables(recipe: Any, tables: Sequence[Path], profile: Path,
                        command: str) -> tuple[dict[str, Any], list[str]]:
    """Steps 1-3: the profile data fitted on the microbenchmark tables, and the report lines."""
    df, machine = read_measurements(list(tables))
    cal = calibrate(df, machine)
    base = lavapipe_base(machine) if recipe.base == "machine" else read_toml(profile)
    data = apply(cal, base, command)
    lines = [command, report(cal)]
    if getattr(recipe, "host_pcie", False):
        lines.append(_host_pcie(data, df))
    if recipe.host_copy_table:
        name = recipe.host_copy_table
        rows = (df[df["source"] == name] if name in {t.name for t in tables}  # loaded above
                else read_measurements([tables[0].parent / name])[0])  # read with the same checks
        lines.append(_host_copy(data, rows, name))
    if recipe.copy_from is not None:
        lines.append(_copy_from(data, recipe))
    return data, lines


def _host_pcie(data: dict[str, Any], df: pd.DataFrame) -> str:
    """The host side of PCIe per direction into `data`'s host: with the most GPUs the tables
    have copying at once, each GPU's rate at the largest size (bytes over the median time, its
    fastest queue family), summed over the GPUs: what the host took from all the links. The
    largest copies, not a fit over the sizes: small copies of several GPUs overlap only in
    part (they start a little apart), so they cross faster than the shared capacity allows."""
    found: dict[str, tuple[float, int, list[float]]] = {}
    for name, path in COPY_PASSES.items():
        rows = df[df["pass"] == name] if "gpus" in df.columns else df.iloc[0:0]
        most = int(rows["gpus"].max()) if rows["gpus"].notna().any() else 1
        if path == "d2d" or most < 2:
            continue
        rows = rows[rows["gpus"] == most]
        rows = rows[rows["bytes"] == rows["bytes"].max()]
        times = rows.groupby(["gpu", "queue"])["duration_ns"].median()
        rates = [float(rows["bytes"].iloc[0]) / float(t.min()) for _, t in times.groupby(level="gpu")]
        found[path] = (sum(rates), most, rates)
        data["host"][f"pcie_{path}_gbps"] = round(sum(rates), 4)
    if not found:
        return "host side of PCIe: no copy rows with several GPUs copying at once; unset"
    parts = "; ".join(f"{path} {total:.4g} GB/s = " + " + ".join(f"{r:.3g}" for r in rates)
                      + f" ({most} GPUs copying at once)" for path, (total, most, rates) in found.items())
    data.setdefault("sources", {})["host_pcie"] = (
        "host.pcie_*_gbps: the sum of the per-GPU copy rates (bytes over the median time of the "
        "largest copy, fastest queue family) with every GPU of the copy tables copying at once, "
        "written by the study's calibration (`host_pcie = true`)")
    return f"host side of PCIe: {parts}"


def refine_on_runs(recipe: Any, data: dict[str, Any], runs: Sequence[Run]) -> tuple[dict[str, Any], list[str]]:
    """Steps 4-6: pass costs, queue gap and host effects fitted on the calibration runs."""
    lines: list[str] = []
    if not runs:
        return data, lines
    fits = fit_passes_from_runs(runs, recipe.run_fitted, recipe.run_fit_gpus, recipe.run_fit_terms,
                                placed_shapes(data))
    data = with_pass_fits(data, fits)
    lines.append(f"refitted on {len(runs)} calibration runs:")
    for kind, f in fits.items():
        terms = ", ".join(f"{n}={v:.4g}+-{e:.2g}" for n, v, e in zip(f.names, f.coef, f.stderr))
        warn = f" ({'; '.join(f.warnings)})" if f.warnings else ""
        lines.append(f"  {kind}: {terms}; rms {f.rel_rms:.1%} ({len(f.rel_residuals)} rows){warn}")
    if recipe.run_fit_alone:
        scales = fit_alone_scales(runs, recipe.run_fit_alone, data["gpus"][0]["costs"])
        data = with_alone_scales(data, scales)
        for kind in recipe.run_fit_alone:
            scale, rows = scales.get(kind, (float("nan"), 0))
            lines.append(f"  {kind}: work terms x {scale:.3g} (median over {rows} instances alone on "
                         f"the cores in multi-GPU runs; fixed cost kept)" if rows else
                         f"  {kind}: no instance ran alone in a multi-GPU calibration run; "
                         f"microbenchmark costs kept")
    if recipe.task_gap:
        gap = fit_task_gap(runs)
        if gap is not None:
            for gpu in data["gpus"]:
                gpu["task_gap_ns"] = gap
            lines.append(f"queue task_gap_ns = {gap} (median idle between tasks of a queue, 1-GPU runs)")
    if recipe.copy_setup:
        for family, (fixed, count) in fit_copy_setup(runs, data).items():
            for gpu in data["gpus"]:
                gpu.setdefault("copy", {}).setdefault(family, {})["fixed_ns"] = fixed
            lines.append(f"copy on {family}: fixed_ns = {fixed} (median of the runs' copies alone on "
                         f"the cores, {count} copies, less bytes over the microbenchmarks' rate)")
    copy_wait = None
    if recipe.host_copy_wake:
        wake = fit_host_copy_wake(runs)
        if wake is not None:
            copy_wait = wake[0]
            dispatch = int(data["host"].get("dispatch_ns", 0))
            data["host"]["host_copy_wake_ns"] = copy_wake_after_dispatch(copy_wait, dispatch)
            lines.append(f"host copy wait {copy_wait} ns (median from a host copy's device input to "
                         f"its start, idle copy thread, {wake[1]} copies) = host_copy_wake_ns + "
                         f"dispatch_ns (the grid search below splits it)")
    if recipe.busy_wake:
        lines.append(_busy_wake(data, runs))
    if recipe.host_grid:
        level = getattr(recipe, "host_grid_level", "prediction")
        found, score = fit_host_effects(data, runs, dict(recipe.host_grid), copy_wait, level)
        data["host"].update(found)
        lines.append(f"host {found} (grid search; mean |{level} frame-time error| {score:.1%} on "
                     f"the calibration runs)")
    return data, lines


def _busy_wake(data: dict[str, Any], runs: Sequence[Run]) -> str:
    """Measure the busy_wake effect on the runs into `data`'s host (before the grid search, so
    that the search sees the model with it)."""
    window = int(data["host"].get("busy_wake_window_ns", BUSY_WAKE_WINDOW_NS))
    found = fit_busy_wake(runs, data, window)
    if found is None:
        return ("host busy_wake: no copy was made ready within the window of another GPU's "
                "core-filling pass in the calibration runs; off")
    data["host"].update(busy_wake_share=round(found.share, 4), busy_wake_ns=found.ns,
                        busy_wake_window_ns=window)
    return (f"host busy_wake_share = {found.share:.4g}, busy_wake_ns = {found.ns} (of {found.pairs} "
            f"(pass, GPU) pairs with a copy made ready within {window / 1e6:g} ms of another "
            f"GPU's core-filling pass starting, those whose copy was left behind; their wait over "
            f"{found.full_waits} pairs whose pass outlasted it)")


def placed_shapes(data: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Pass kinds whose microbenchmark fit has placed terms (a mesh's visible triangles, ...):
    their per-term coefficients, which a refit on whole-frame runs keeps in proportion (the
    runs cannot tell those terms apart; the microbenchmarks measured them over placements)."""
    costs = data["gpus"][0].get("costs", {}) if data.get("gpus") else {}
    return {kind: {k.removeprefix("ns_per_"): float(v) for k, v in costs[kind].items()
                   if k.startswith("ns_per_")}
            for kind, placed in PLACED_TERMS.items()
            if kind in costs and any(float(costs[kind].get(f"ns_per_{t}", 0)) > 0 for t in placed)}


def _host_copy(data: dict[str, Any], table: pd.DataFrame, name: str) -> str:
    """Host copy on the profile's memcpy threads as fixed + bytes / B (the model's parts run in
    parallel, each paying host_copy_fixed_ns), from the rows of measure table `name`."""
    host = data["host"]
    threads = int(host["memcpy_threads"])
    d = table[table["threads"] == threads]
    fit = fit_copy_line(d, "host copy")
    fixed, gbps = float(fit.coef[0]), 1.0 / float(fit.coef[1])
    host.update(host_copy_fixed_ns=int(round(fixed)), memory_bandwidth_gbps=round(gbps, 3),
                memcpy_thread_gbps=round(gbps / threads, 4))
    return (f"host copy on {threads} threads ({name}, {len(d)} rows): {fixed / 1e3:.0f} us + "
            f"bytes / {gbps:.1f} GB/s" + "".join(f"; {w}" for w in fit.warnings))


def _copy_from(data: dict[str, Any], recipe: Any) -> str:
    other = read_toml(recipe.copy_from)
    for gpu in data["gpus"]:
        for kind in recipe.copy_costs:
            gpu["costs"][kind] = copy.deepcopy(other["gpus"][0]["costs"][kind])
    for key in recipe.copy_host:
        data["host"][key] = other["host"][key]
    return (f"{', '.join(recipe.copy_costs + recipe.copy_host)}: copied from "
            f"{recipe.copy_from.name}")
