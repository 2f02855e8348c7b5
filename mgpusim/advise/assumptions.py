"""What the advice assumed about the frame, and how far the answer moves if that is off.

A captured pass's `pixel_share` (how much of its time scales with the pixels it draws, the
rest with its geometry) decides how far sort-first scales, and a capture rarely states it:
`mgpusim frame import` infers it from the pass's name, targets and reads and records how in the
experiment file (:mod:`mgpusim.frames.shares`). :func:`check_shares` lists every pass's share
with where it came from and runs the best options again with every assumed share (those the
capture did not state) :data:`SHARE_DELTA` lower and higher, clamped to 0..1: the best of each
schedule and GPU count and the first rows of the ranking, at full fidelity, evenly paced AFR
with its cadence found again.
"""
from __future__ import annotations

import copy
import time
from typing import Any, Mapping

import pandas as pd

from mgpusim.advise.advisor import (
    Advice,
    Batch,
    Cadences,
    Progress,
    by_option,
    cell,
    paced,
    paced_sources,
    ran,
    ranking,
    two_eye_passes,
)
from mgpusim.advise.worker_set import Tally, Workers, workers_of
from mgpusim.frames.shares import Share, recorded_shares

#: How far the assumed shares are moved, each way.
SHARE_DELTA = 0.25
#: Besides the best of each schedule and GPU count: the first rows of the ranking re-run.
TOP_ROWS = 10


def shares(advice: Advice) -> dict[str, Share]:
    """The captured passes' shares and where each came from."""
    passes = [p for p in advice_scene(advice) if p.get("kind") == "captured"]
    return recorded_shares(advice.experiment, {str(p["name"]): float(p["pixel_share"]) for p in passes})


def advice_scene(advice: Advice) -> list[dict[str, Any]]:
    """The experiment's scene passes as the search ran them (with `advise --set` applied)."""
    from mgpusim.schedules.experiment import load_experiment  # noqa: PLC0415 - keeps this module light
    return list(load_experiment(advice.experiment, advice.base).raw["scene"]["passes"])


def shifted(passes: list[dict[str, Any]], assumed: set[str], delta: float) -> list[dict[str, Any]]:
    """The passes with every assumed share moved by `delta`, clamped to 0..1."""
    out = copy.deepcopy(passes)
    for p in out:
        if p.get("kind") == "captured" and p["name"] in assumed:
            p["pixel_share"] = min(1.0, max(0.0, float(p["pixel_share"]) + delta))
    return out


def candidates(advice: Advice) -> list[int]:
    """The options re-run: the best row of each schedule and GPU count, and the first
    :data:`TOP_ROWS` rows of the ranking (the baseline among them)."""
    rows = advice.ranked.drop_duplicates("rank")
    chosen = {0, *rows.index[:TOP_ROWS], *rows.groupby(["family", "gpus"], sort=False).head(1).index}
    return sorted(int(i) for i in chosen)


def check_shares(advice: Advice, workers: int | Workers = 1, delta: float = SHARE_DELTA,
                 progress: Progress | None = None) -> dict[str, Any]:
    """Every captured pass's share and its source (`passes`), and per direction (`shifts`) the
    best option with the assumed shares moved by -`delta` and +`delta`, where today's best
    lands then, and each schedule's best measure today and then (`families`). Kept in
    `advice.assumptions` (which the report shows) and returned; its time in `advice.timings`.
    `workers`: a count of processes, or a command's :class:`Workers` (both directions' runs
    are handed to them together)."""
    t0 = time.perf_counter()
    with workers_of(workers) as pool:
        advice.assumptions = _check(advice, pool, delta, progress)
    advice.timings["shares_s"] = time.perf_counter() - t0
    return advice.assumptions


def _check(advice: Advice, workers: Workers, delta: float, progress: Progress | None) -> dict[str, Any]:
    table = shares(advice)
    listed = [{"pass": name, "pixel_share": s.value, "geometry_share": 1 - s.value, "source": s.source,
               "why": s.why} for name, s in table.items()]
    assumed = {name for name, s in table.items() if s.assumed}
    out: dict[str, Any] = {"passes": listed, "delta": delta, "assumed": sorted(assumed), "shifts": []}
    if not assumed:
        return out
    scene = advice_scene(advice)
    best = advice.ranked.iloc[0]
    runs = {sign: _Rerun(advice, candidates(advice), shifted(scene, assumed, sign * delta), workers,
                         progress, f"assumed shares {sign * delta:+g}") for sign in (-1, 1)}
    for run in runs.values():  # each direction's cadences queued as soon as its means are in
        run.pace()
    for sign, run in runs.items():
        got = run.ranked()
        if got.empty:
            continue
        first = got.iloc[0]
        now = got.loc[got.index == best.name]
        today = advice.ranked.loc[[i for i in got.index if i in advice.ranked.index]]
        moved = {str(family): {"now_ms": float(today.loc[today["family"] == family, "rank_ms"].min()),
                               "shifted_ms": float(group["rank_ms"].min())}
                 for family, group in got.groupby("family", sort=False)}
        out["shifts"].append({
            "delta": sign * delta, "best": str(first["label"]), "best_option": int(got.index[0]),
            "best_rank_ms": float(first["rank_ms"]), "best_latency_ms": float(first["latency_ms"]),
            "same": bool(len(now)) and int(now["rank"].iloc[0]) == 1,
            "today_best_rank_ms": float(now["rank_ms"].iloc[0]) if len(now) else None,
            "today_best_rank": int(now["rank"].iloc[0]) if len(now) else None,
            "families": moved, "options": len(got)})
    return out


class _Rerun:
    """The picked options at full fidelity on the scene `passes`, handed to the workers:
    :meth:`pace` hands in the paced options' cadences once their unpaced options' means are
    in, :meth:`ranked` ranks what came back as the search ranks."""

    def __init__(self, advice: Advice, picks: list[int], passes: list[dict[str, Any]], workers: Workers,
                 progress: Progress | None = None, stage: str = "assumed shares"):
        self.advice, self.picks, self.passes, self.workers = advice, picks, passes, workers
        self.progress, self.stage = progress, stage
        self.base = {**advice.base, "scene.passes": passes}
        opts = advice.options
        plain = sorted({i for i in picks if opts[i].paced_from is None}
                       | {u for i in picks if (u := opts[i].paced_from) is not None})
        items: list[tuple[int, Mapping[str, Any]]] = [(i, _on_scene(opts[i].overrides, passes)) for i in plain]
        self.plain = Batch(workers, advice.experiment, self.base, items, "full",
                           tally=Tally(progress, stage, len(items)))
        self.rows = pd.DataFrame()
        self.cadences: Cadences | None = None

    def pace(self) -> None:
        """Evenly paced AFR: its cadence again, from its unpaced option's mean on this scene."""
        opts = self.advice.options
        self.rows = by_option(self.plain.rows())
        means = {u: float(cell(self.rows, u, "frame_time_ms")) for u in paced_sources(opts, self.picks)
                 if ran(self.rows, u)}
        shifted_opts = [o if "scene.passes" not in o.overrides else
                        type(o)(o.family, o.gpus, o.link, o.settings, _on_scene(o.overrides, self.passes),
                                o.paced_from, o.detail) for o in opts]
        self.cadences = Cadences(self.workers, self.advice.experiment, self.base, shifted_opts, means, "full",
                                 stage=(self.progress, f"{self.stage}, even pacing"))

    def ranked(self) -> pd.DataFrame:
        """The picked options that ran, best first, with the search's ranking columns."""
        if self.cadences is None:
            self.pace()
        assert self.cadences is not None
        advice, opts, rows = self.advice, self.advice.options, self.rows
        sources = paced_sources(opts, self.picks)
        extra = []
        labels = {i: opts[i].label for i in self.picks}
        for u, (pace, row) in self.cadences.best().items():
            extra.append({**row, "option": sources[u]})
            labels[sources[u]] = paced(opts[u], u, pace).label
        if extra:
            rows = pd.concat([rows.drop(index=[i for i in sources.values() if i in rows.index]), by_option(extra)])
        rows = rows.loc[[i for i in self.picks if i in rows.index]]
        rows = rows[rows["error"].isna()].copy()
        if rows.empty:
            return rows
        meta = advice.table.loc[rows.index, ["family", "gpus", "link", "settings"]]
        rows = rows.join(meta)
        rows["label"] = [labels[int(i)] for i in rows.index]
        rows["rank_ms"] = rows[["frame_time_ms", "interval_p99_ms"]].max(axis=1)
        order = ranking(rows, advice.link_order)
        rows = rows.join(order)
        return rows.sort_values("order")


def _on_scene(overrides: Mapping[str, Any], passes: list[dict[str, Any]]) -> dict[str, Any]:
    """An option's overrides on another scene: a stereo frame's two-eye copy made from it."""
    out = dict(overrides)
    if "scene.passes" in out:
        out["scene.passes"] = two_eye_passes(passes)
    return out
