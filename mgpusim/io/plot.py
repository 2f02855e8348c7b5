"""Timeline pictures: one row per GPU queue, copy engine, host thread and link direction.

Works on any trace in the common schema; `frames` limits the picture to a window of frames
so that long runs stay readable. Files are drawn on matplotlib Figures without pyplot: no
display needed and no global backend switched (a notebook's inline plots keep working).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence, cast

import numpy as np
import pandas as pd
from matplotlib import patheffects, rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.image import imsave
from matplotlib.layout_engine import ConstrainedLayoutEngine

from mgpusim.results.summary import link_track

STEP_COLOURS = {
    "render": "#4c72b0", "d2h": "#dd8452", "host_copy": "#937860", "h2d": "#55a868",
    "composite": "#c44e52", "present": "#8172b3", "link": "#bbbbbb",
}
#: Colours for steps not in STEP_COLOURS, handed out in the order of the steps' names.
_MORE_COLOURS = ("#da8bc3", "#ccb974", "#64b5cd", "#8c8c8c", "#17becf", "#bcbd22", "#ff7f0e",
                 "#9467bd", "#2ca02c", "#d62728", "#1f77b4", "#e377c2")
#: Frame numbers are written on slices at least this fraction of the window wide.
_LABEL_MIN_WIDTH = 0.025


def step_colours(steps: Sequence[str]) -> dict[str, str]:
    """A distinct colour per step: the usual steps keep theirs, others get the next free one."""
    out = {s: STEP_COLOURS[s] for s in steps if s in STEP_COLOURS}
    spare = [c for c in _MORE_COLOURS if c not in out.values()]
    for i, step in enumerate(sorted(s for s in set(steps) if s not in STEP_COLOURS)):
        out[step] = spare[i % len(spare)]
    return out


def _rows(trace: pd.DataFrame) -> list[str]:
    labels = (trace["device"].astype(str) + "." + trace["engine"].astype(str)).unique().tolist()

    def key(label: str) -> tuple:
        dev, _, eng = label.partition(".")
        num = int(eng[6:]) if eng.startswith("thread") and eng[6:].isdigit() else -1
        return (dev == "host", dev, eng.startswith("link"), num, eng)
    return sorted(labels, key=key)


def draw_timeline(ax, trace: pd.DataFrame, links: pd.DataFrame | None = None,
                  title: str = "", frames: Sequence[int] | None = None) -> None:
    """Draw one timeline on `ax`: time in ms on x from the window's first start, a row per
    queue, engine, host thread and link direction, slices coloured by step and numbered by
    frame where they are wide enough, frame ends marked on the top axis, the legend outside."""
    df = trace
    if frames is not None:
        df = df[df["frame"].isin(list(frames))]
    if len(df) == 0:
        ax.set_title(title + " (no frames in the window)")
        return
    lo, hi = int(df["start_ns"].min()), int(df["end_ns"].max())
    parts = [df.assign(label=df["device"].astype(str) + "." + df["engine"].astype(str))]
    if links is not None and len(links):
        lk = links[(links["end_ns"] > lo) & (links["start_ns"] < hi)]
        parts.append(pd.DataFrame({"label": lk["channel"].astype(str).map(lambda c: ".".join(link_track(c))),
                                   "start_ns": lk["start_ns"].clip(lo, hi), "end_ns": lk["end_ns"].clip(lo, hi),
                                   "step": "link", "frame": -1}))
    both = pd.concat(parts, ignore_index=True)
    rows = _rows(both.assign(device=both["label"].str.partition(".")[0], engine=both["label"].str.partition(".")[2]))
    y = {label: i for i, label in enumerate(reversed(rows))}
    colours = step_colours(both["step"].astype(str).unique().tolist())
    for step, group in both.groupby("step", sort=False):
        ax.add_collection(_bars(group, y, lo, colours[str(step)], str(step)))
    _frame_labels(ax, both, y, lo, hi)
    ax.set_yticks(range(len(rows)), list(reversed(rows)), fontsize=7)
    ax.set_xlabel("time (ms)")
    ax.set_xlim(0, (hi - lo) / 1e6 * 1.01)
    ax.set_title(title, fontsize=9)
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles))
    ax.legend(uniq.values(), uniq.keys(), fontsize=7, title="step", title_fontsize=7,
              loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0.0)


def _bars(group: pd.DataFrame, y: dict[str, int], lo: int, colour: str, step: str) -> PolyCollection:
    """One step's slices as one collection, a rectangle per slice on its row (0.8 high), the
    rows in order and each row's slices in the trace's order, as `broken_barh` per row drew
    them. Why one: an artist per step and row cost more to make and draw than its bars."""
    group = group.assign(_row=group["label"].astype(str)).sort_values("_row", kind="stable")
    x0 = ((group["start_ns"] - lo) / 1e6).to_numpy(dtype=float)
    x1 = x0 + ((group["end_ns"] - group["start_ns"]) / 1e6).clip(lower=1e-6).to_numpy(dtype=float)
    y0 = group["_row"].map(y).to_numpy(dtype=float) - 0.4
    y1 = y0 + 0.8
    verts = np.stack([np.column_stack(c) for c in ((x0, y0), (x0, y1), (x1, y1), (x1, y0))], axis=1)
    # (an (N, 4, 2) array is a sequence of rectangles: PolyCollection takes it whole)
    return PolyCollection(cast(Sequence[np.ndarray], verts), facecolors=colour, edgecolor="black", linewidth=0.2,
                          label=step)


def _frame_labels(ax, both: pd.DataFrame, y: dict[str, int], lo: int, hi: int) -> None:
    """Frame numbers on the slices wide enough to hold one, and each frame's end (its last
    task) as a tick on the top axis."""
    tasks = both[both["frame"] >= 0]
    wide = tasks[(tasks["end_ns"] - tasks["start_ns"]) >= _LABEL_MIN_WIDTH * max(hi - lo, 1)]
    for label, frame, s, e in zip(wide["label"], wide["frame"], wide["start_ns"], wide["end_ns"]):
        ax.text(((s + e) / 2 - lo) / 1e6, y[label], str(int(frame)), ha="center", va="center", fontsize=6,
                color="white", fontweight="bold", clip_on=True)
    ends = tasks.groupby("frame")["end_ns"].max()
    top = ax.secondary_xaxis("top")
    top.set_xticks(((ends - lo) / 1e6).tolist(), [str(int(f)) for f in ends.index], fontsize=6)
    top.set_xlabel("frame ends (frame number)", fontsize=7)
    for x in (ends - lo) / 1e6:
        ax.axvline(x, color="#444444", linewidth=0.4, linestyle=":", zorder=0)


def last_frames(trace: pd.DataFrame, count: int = 4) -> list[int]:
    top = int(trace["frame"].max()) if len(trace) else 0
    return list(range(max(0, top - count + 1), top + 1))


def timeline_png(trace: pd.DataFrame, path: str | Path, links: pd.DataFrame | None = None,
                 title: str = "", frames: Sequence[int] | None = None, channels: int | None = None) -> Path:
    """Write a timeline PNG of `frames` (default: the last four frames). `channels`: the link
    rows to size the figure for (default: the channels in `links`; a long run passes only the
    links of the window, and the count of all its channels)."""
    frames = last_frames(trace) if frames is None else frames
    if channels is None:
        channels = 0 if links is None else links["channel"].nunique()
    n_rows = max(3, len(_rows(trace)) + channels)
    fig = Figure(figsize=(13, 1.6 + 0.3 * n_rows))
    ax = fig.subplots()
    draw_timeline(ax, trace, links, title, frames)
    return save_tight(fig, path, 110)


def save_tight(fig: Figure, path: str | Path, dpi: int) -> Path:
    """`fig` as `savefig(path, dpi=dpi, bbox_inches="tight")` writes it, drawn once: the
    figure is rendered whole and the picture cut to the padded box of its artists (within a
    pixel of where savefig's second render puts them). Why: savefig's tight box takes a layout
    pass of its own before it draws, a fifth of a timeline's time. A box reaching past the
    figure (a label wider than it) is drawn again by savefig, as before."""
    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(dpi)
    canvas.draw()
    box = fig.get_tightbbox(canvas.get_renderer()).padded(rcParams["savefig.pad_inches"])
    width, height = fig.get_size_inches()
    if box.x0 < 0 or box.y0 < 0 or box.x1 > width or box.y1 > height:
        fig.savefig(path, dpi=dpi, bbox_inches=box)
        return Path(path)
    left, top = round(box.x0 * dpi), round((height - box.y1) * dpi)
    pixels = np.asarray(canvas.buffer_rgba())
    cut = pixels[top:top + int(box.height * dpi), left:left + int(box.width * dpi)]
    imsave(path, cut, format="png", origin="upper", dpi=dpi)
    return Path(path)


def comparison_png(measured: pd.DataFrame, simulated: pd.DataFrame, path: str | Path, title: str = "",
                   frames: Sequence[int] | None = None, sim_links: pd.DataFrame | None = None) -> Path:
    """Measured and simulated timelines one above the other: the same frames, one time axis
    (each from its window's first start, on the same scale and range), both with their own
    tick labels and frame ends, laid out so that no label overlaps another (constrained
    layout). A measured steady window of frames the (shorter) simulation does not have is
    drawn beside the simulation's last frames, as many of them: both in steady state."""
    frames, sim_frames = comparison_frames(measured, simulated, frames)
    rows = max(len(_rows(measured)), len(_rows(simulated)), 3)
    # constrained layout, with room for the lower panel's frame-end axis under the upper's labels
    fig = Figure(figsize=(12, 3.2 + 0.6 * rows), layout=ConstrainedLayoutEngine(h_pad=0.12, hspace=0.08))
    top, bottom = fig.subplots(2, 1, sharex=True)
    lo_m = measured[measured["frame"].isin(list(frames))]
    lo_s = simulated[simulated["frame"].isin(sim_frames)]
    draw_timeline(top, lo_m, None, f"measured: {title}, {_frames_text(frames)}", frames)
    same = "" if sim_frames == frames else f" (the run's last {len(sim_frames)})"
    draw_timeline(bottom, lo_s, sim_links, f"simulated: {title}, {_frames_text(sim_frames)}{same}", sim_frames)
    top.tick_params(labelbottom=True)  # sharex hides an upper panel's tick labels: keep them
    span = max(_span(lo_m), _span(lo_s))
    bottom.set_xlim(0, span * 1.02 if span else 1)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return Path(path)


def _frames_text(frames: Sequence[int]) -> str:
    return f"frames {frames[0]}-{frames[-1]}" if len(frames) > 1 else f"frame {frames[0]}" if frames else "no frames"


def comparison_frames(measured: pd.DataFrame, simulated: pd.DataFrame,
                      frames: Sequence[int] | None = None) -> tuple[list[int], list[int]]:
    """The measured frames to draw (default its last four) and the simulated ones: the same
    numbers where the simulation has them, else its last frames, as many."""
    frames = list(last_frames(measured) if frames is None else frames)
    if set(frames) <= set(simulated["frame"].unique()):
        return frames, frames
    return frames, last_frames(simulated, len(frames))


def _span(df: pd.DataFrame) -> float:
    return (int(df["end_ns"].max()) - int(df["start_ns"].min())) / 1e6 if len(df) else 0.0


def sweep_png(table: pd.DataFrame, keys: Sequence[str], path: str | Path, metric: str = "frame_time_ms") -> Path:
    """:func:`draw_sweep` into a PNG file."""
    fig = Figure(figsize=(8, 4.8))
    draw_sweep(fig.subplots(), table, keys, metric)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    return Path(path)


#: Most lines a sweep plot draws (one per combination of the keys after the first); a grid
#: with more is drawn as a heatmap of its first two keys, the mean over the others.
MAX_SWEEP_LINES = 12
#: Most heatmap cells written with their value (more are hard to read, and each label costs
#: more to draw than the image: 100 labels take about a second).
MAX_CELL_LABELS = 36
#: Most tick labels on a heatmap's axis (every n-th value is named beyond it).
MAX_TICKS = 24


def draw_sweep(ax, table: pd.DataFrame, keys: Sequence[str], metric: str = "frame_time_ms") -> None:
    """A sweep's `metric` against its keys on `ax`: a line for one key, a heatmap for two
    (failed cells say so), and for more a line over the first key for each combination of
    the others, or, beyond MAX_SWEEP_LINES of them, a heatmap of the first two keys averaged
    over the others (one image whatever the grid's size). Failed points are left out of lines
    and averages (their rows carry the error)."""
    ok = table[table["error"].isna()] if "error" in table else table
    if metric not in ok or ok[metric].isna().all():
        ax.text(0.5, 0.5, f"no point has a {metric}", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
    elif len(keys) == 2 or len(keys) > 2 and _combinations(table, keys[1:]) > MAX_SWEEP_LINES:
        failed = table["error"].notna() if "error" in table else pd.Series(False, index=table.index)
        _heatmap(ax.figure, ax, table.assign(**{metric: table[metric].mask(failed)}), keys, metric)
    else:
        _lines(ax, ok, keys, metric)


def _combinations(table: pd.DataFrame, keys: Sequence[str]) -> int:
    return int(np.prod([table[k].nunique(dropna=False) for k in keys]))


def _heatmap(fig, ax, df: pd.DataFrame, keys: Sequence[str], metric: str) -> None:
    """The mean of `metric` per (first key, second key) cell, with numpy (cheap at any size);
    a cell whose points all failed is blank and, where cells are labelled, says so."""
    rows, row_values = _codes(df[keys[0]])
    cols, col_values = _codes(df[keys[1]])
    values = df[metric].to_numpy(dtype=float)
    good = ~np.isnan(values)
    cell = rows * len(col_values) + cols
    size = len(row_values) * len(col_values)
    total = np.bincount(cell[good], values[good], minlength=size)
    count = np.bincount(cell[good], minlength=size)
    with np.errstate(invalid="ignore"):
        grid = (total / count).reshape(len(row_values), len(col_values))
    image = ax.imshow(grid, aspect="auto", cmap="viridis_r", origin="lower", interpolation="nearest")
    _ticks(ax.set_xticks, col_values)
    _ticks(ax.set_yticks, row_values)
    ax.set_xlabel(keys[1])
    ax.set_ylabel(keys[0])
    if grid.size <= MAX_CELL_LABELS:
        outline = [patheffects.withStroke(linewidth=2, foreground="white")]
        for (i, j), value in np.ndenumerate(grid):
            ax.text(j, i, f"{value:.3g}" if value == value else "failed", ha="center", va="center",
                    fontsize=8, color="black", path_effects=outline)
    fig.colorbar(image, ax=ax, label=metric)
    over = f", mean over {', '.join(keys[2:])}" if len(keys) > 2 else ""
    ax.set_title(f"{metric} by {keys[0]} and {keys[1]}{over}", fontsize=10, wrap=True)


def _codes(column: pd.Series) -> tuple[np.ndarray, list]:
    """Each row's position among the column's sorted distinct values, and those values."""
    codes, uniques = pd.factorize(column, sort=True)
    return codes, list(uniques)


def _ticks(set_ticks, values: list) -> None:
    step = max(1, -(-len(values) // MAX_TICKS))
    at = list(range(0, len(values), step))
    set_ticks(at, [str(values[i]) for i in at])


def _lines(ax, df: pd.DataFrame, keys: Sequence[str], metric: str) -> None:
    x_key, others = keys[0], list(keys[1:])
    numeric = pd.api.types.is_numeric_dtype(df[x_key])
    order = sorted(df[x_key].unique(), key=lambda v: (str(type(v)), v))
    groups = df.groupby(others, sort=True) if others else [((), df)]
    for label, group in groups:
        group = group.sort_values(x_key, key=lambda s: s.map(order.index)) if not numeric else group.sort_values(x_key)
        x = group[x_key] if numeric else group[x_key].map(order.index)
        name = ", ".join(f"{k}={v}" for k, v in zip(others, label if isinstance(label, tuple) else (label,)))
        ax.plot(x, group[metric], marker="o", label=name or None)
    if not numeric:
        ax.set_xticks(range(len(order)), [str(v) for v in order])
    ax.set_xlabel(x_key)
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)
    if others:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1), borderaxespad=0)
    ax.set_title(f"{metric} by {', '.join(keys)}", fontsize=10)


#: Marker colours of schedule families in a Pareto plot, in the order they are first seen.
_FAMILY_COLOURS = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3", "#937860", "#da8bc3")


def pareto_png(table: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """Frame time against latency of a search's options: every option the fast level ran
    (grey), those confirmed at full fidelity coloured by `family`, the Pareto front joined by a
    line, the one-GPU baseline (`gpus` 1) ringed. Columns: fast_frame_time_ms, fast_latency_ms,
    frame_time_ms, latency_ms, family, gpus, confirmed, pareto."""
    fig = Figure(figsize=(8, 5.2))
    ax = fig.subplots()
    fast = table[table["fast_frame_time_ms"].notna()]
    ax.scatter(fast["fast_frame_time_ms"], fast["fast_latency_ms"], s=6, color="#c8c8c8",
               label="analytic level (not confirmed)", zorder=1)
    done = table[table["confirmed"]]
    for i, (family, group) in enumerate(done.groupby("family", sort=False)):
        ax.scatter(group["frame_time_ms"], group["latency_ms"], s=22 + 6 * group["gpus"],
                   color=_FAMILY_COLOURS[i % len(_FAMILY_COLOURS)], edgecolor="black",
                   linewidth=0.4, label=f"{family} (full)", zorder=3)
    front = done[done["pareto"]].sort_values("frame_time_ms")
    if len(front):
        ax.step(front["frame_time_ms"], front["latency_ms"], where="post", color="black",
                linewidth=0.8, zorder=2, label="Pareto front")
    base = done[done["gpus"] == 1]
    if len(base):
        ax.scatter(base["frame_time_ms"], base["latency_ms"], s=160, facecolor="none",
                   edgecolor="red", linewidth=1.2, zorder=4, label="one GPU (baseline)")
    ax.set_xlabel("frame time (ms)")
    ax.set_ylabel("latency (ms)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1), borderaxespad=0)
    ax.set_title(title or "options: frame time against latency (marker size: GPUs)", fontsize=10)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return Path(path)


def errors_png(table: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """A study's frame-time errors per configuration (simulated / measured - 1, in %): the
    prediction's bar and, where compared, the replay's beside it. Columns: config,
    frame_time_error, replay_frame_time_error (optional)."""
    rows = table.reset_index(drop=True)
    y = np.arange(len(rows))
    fig = Figure(figsize=(8, 1.2 + 0.28 * len(rows)))
    ax = fig.subplots()
    replay = rows["replay_frame_time_error"] if "replay_frame_time_error" in rows else None
    height = 0.4 if replay is not None else 0.8
    ax.barh(y - (height / 2 if replay is not None else 0), 100 * rows["frame_time_error"], height,
            color="#4c72b0", label="prediction (calibrated costs)")
    if replay is not None:
        ax.barh(y + height / 2, 100 * replay.fillna(0.0), height, color="#dd8452",
                label="replay (measured durations)")
    ax.axvline(0, color="black", linewidth=0.6)
    ax.set_yticks(y, rows["config"], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("frame-time error (%): simulated / measured - 1")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title, fontsize=10)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    return Path(path)
