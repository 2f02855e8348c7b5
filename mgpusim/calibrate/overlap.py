"""Overlap efficiencies of the queues of one GPU, from `mgpusim measure --pass overlap` rows.

Each measured size of each pair gives one efficiency, from the fastest of its repetitions (A
alone, B alone, both at once: the least disturbed run of each); a pair's efficiency is the
median over its sizes. Rows whose pair ran on a fallback queue (a family the device lacks) say
nothing about that pair (both pieces ran on one queue, one after the other) and are left out
with a warning.
"""
from __future__ import annotations

from typing import Any

import pandas as pd

from ..sim.executors import overlap_efficiency

#: Columns that tell one measured configuration of the overlap pass from another.
_CONFIG = ("pair", "width", "height", "iterations", "particles", "bytes", "copy", "queue_a",
           "queue_b", "missing")


def fastest_of(df: pd.DataFrame) -> pd.DataFrame:
    """One row per measured configuration of the overlap pass: the fastest A alone, B alone and
    together of its repetitions, and the efficiency they give."""
    rows = df[df["pass"] == "overlap"].copy()
    if rows.empty:
        return pd.DataFrame(columns=[*_CONFIG, "alone_a_ns", "alone_b_ns", "duration_ns", "efficiency"])
    rows["missing"] = rows["missing"].fillna("") if "missing" in rows else ""
    keys = [c for c in _CONFIG if c in rows.columns]
    best = rows.groupby(keys, sort=False, dropna=False)[["alone_a_ns", "alone_b_ns", "duration_ns"]].min()
    best = best.reset_index()
    best["efficiency"] = [overlap_efficiency(a, b, t) for a, b, t in
                          zip(best["alone_a_ns"], best["alone_b_ns"], best["duration_ns"])]
    return best


def fit_overlap(df: pd.DataFrame) -> tuple[dict[str, tuple[float, list[float]]], list[str]]:
    """{pair: (median efficiency over its sizes, each size's)} and warnings."""
    best = fastest_of(df)
    out: dict[str, tuple[float, list[float]]] = {}
    warnings: list[str] = []
    for pair, group in best.groupby("pair", sort=False):
        usable = group[group["queue_a"] != group["queue_b"]]
        if usable.empty:
            warnings.append(f"overlap {pair}: {group['missing'].iloc[0]}: not fitted")
            continue
        effs = [float(e) for e in usable["efficiency"]]
        out[str(pair)] = (float(pd.Series(effs).median()), effs)
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
        gpu.setdefault("queue_overlap", {}).update({p: round(v, 3) for p, (v, _) in overlap.items()})
    return "queue_overlap: " + ", ".join(
        f"{p}={v:.3f} (sizes: {', '.join(f'{e:.2f}' for e in effs)})" for p, (v, effs) in overlap.items())
