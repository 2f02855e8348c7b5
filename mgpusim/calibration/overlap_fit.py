"""Overlap efficiencies of the queues of one GPU, from `mgpusim measure --pass overlap` rows.

Each measured size of each pair (and graphics work: the fragment loop is the GPU's default,
another pass kind gets a table of its own, `queue_overlap.<kind>`) gives one efficiency, from
the fastest of its repetitions (A alone, B alone, both at once: the least disturbed run of
each); a pair's efficiency is the median over its sizes. Rows whose pair ran on a fallback
queue (a family the device lacks) say nothing about that pair (both pieces ran on one queue,
one after the other) and are left out with a warning.
"""
from __future__ import annotations

from typing import Any

import pandas as pd

from mgpusim.model.costs import overlap_efficiency

#: Columns that tell one measured configuration of the overlap pass from another.
_CONFIG = ("pair", "graphics", "width", "height", "iterations", "particles", "bytes", "copy",
           "queue_a", "queue_b", "missing")
#: The graphics work of tables measured before it could be chosen, and the default's.
DEFAULT_GRAPHICS = "fragment_loop"
#: Pairs with graphics work in them: their efficiency depends on which graphics work it is.
_WITH_GRAPHICS = ("graphics_compute", "graphics_transfer", "devices")


def fastest_of(df: pd.DataFrame) -> pd.DataFrame:
    """One row per measured configuration of the overlap pass: the fastest A alone, B alone and
    together of its repetitions, and the efficiency they give."""
    rows = df[df["pass"] == "overlap"].copy()
    if rows.empty:
        return pd.DataFrame(columns=[*_CONFIG, "alone_a_ns", "alone_b_ns", "duration_ns", "efficiency"])
    rows["missing"] = rows["missing"].astype(object).fillna("") if "missing" in rows else ""
    rows["graphics"] = (rows["graphics"].astype(object).fillna(DEFAULT_GRAPHICS) if "graphics" in rows
                        else DEFAULT_GRAPHICS)
    keys = [c for c in _CONFIG if c in rows.columns]
    best = rows.groupby(keys, sort=False, dropna=False)[["alone_a_ns", "alone_b_ns", "duration_ns"]].min()
    best = best.reset_index()
    best["efficiency"] = [overlap_efficiency(a, b, t) for a, b, t in
                          zip(best["alone_a_ns"], best["alone_b_ns"], best["duration_ns"])]
    return best


def fit_overlap(df: pd.DataFrame) -> tuple[dict[str, tuple[float, list[float]]], list[str]]:
    """{key: (median efficiency over its sizes, each size's)} and warnings. The key is the pair
    (with the default graphics work, the fragment loop), or `kind.pair` for a pair measured with
    another graphics work (`particle_render.graphics_transfer`)."""
    best = fastest_of(df)
    out: dict[str, tuple[float, list[float]]] = {}
    warnings: list[str] = []
    best["key"] = [p if g == DEFAULT_GRAPHICS or p not in _WITH_GRAPHICS else f"{g}.{p}"
                   for p, g in zip(best["pair"], best["graphics"])]
    for key, group in best.groupby("key", sort=False):
        usable = group[group["queue_a"] != group["queue_b"]]
        if usable.empty:
            warnings.append(f"overlap {key}: {group['missing'].iloc[0]}: not fitted")
            continue
        effs = [float(e) for e in usable["efficiency"]]
        out[str(key)] = (float(pd.Series(effs).median()), effs)
    return out, warnings


def apply_overlap(profile: dict[str, Any], overlap: dict[str, tuple[float, list[float]]]) -> str | None:
    """Write the fitted efficiencies into every GPU's `queue_overlap` (real GPUs only: on
    CPU-emulated GPUs the host's cores are the shared resource, modelled by host.cpu); the
    report line, None when there is nothing to say."""
    if not overlap:
        return None
    if profile.get("host", {}).get("gpus_share_cpu"):
        return ("overlap efficiencies not written: these GPUs share the host CPU, which the "
                "profile models (host.cpu_cores)")
    for gpu in profile["gpus"]:
        table = gpu.setdefault("queue_overlap", {})
        for key, (value, _) in overlap.items():
            kind, _, pair = key.rpartition(".")
            (table.setdefault(kind, {}) if kind else table)[pair] = round(value, 3)
    return overlap_line(overlap)


def overlap_line(overlap: dict[str, tuple[float, list[float]]]) -> str:
    """The fitted efficiencies in one line, with each size's."""
    return "queue_overlap: " + ", ".join(
        f"{p}={v:.3f} (sizes: {', '.join(f'{e:.2f}' for e in effs)})" for p, (v, effs) in overlap.items())
