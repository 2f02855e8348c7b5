"""The folder `mgpusim advise` writes: the options table, the answer as JSON, the Pareto plot,
timelines and Perfetto traces of the best options, and one static HTML page over them all.

    OUT/advice.csv      every option: schedule, GPUs, link, analytic and full results, rank
    OUT/advice.json     the answer: best, Pareto front, baseline, how the search went
    OUT/pareto.png      frame time against latency of every option
    OUT/timelines/K_*/  the one-GPU baseline and the best options simulated at full fidelity
                        (summary.json, trace.parquet, timeline.png, trace.perfetto.json)
    OUT/report.html     the page (docs/outputs.md, "Advice")

The set is written into OUT/.advice-partial and moved into place at the end, the report last,
and an earlier advice in OUT is removed before, its report first (:func:`discard_stale`): a run
killed at any point leaves either one frame's complete advice or no report at all, never an old
report beside a new table.
"""
from __future__ import annotations

import os
import re
import shutil
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from mgpusim.advise.advisor import PACE_MARGINS, PACED, RANK_MEASURE, TIE, Advice, Progress, option_command
from mgpusim.advise.worker_set import Tally, Workers, workers_of
from mgpusim.io.plot import pareto_png
from mgpusim.io.report_page import Section, write_page
from mgpusim.io.writers import write_json, write_result, write_table
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

#: Options within this share of the best measure count as as fast (the answer then names the
#: one with the fewest GPUs among them too).
NEAR_BEST = 0.05
_COLUMNS = ("rank", "order", "label", "family", "gpus", "link", "settings", "also_on",
            "fast_frame_time_ms", "fast_interval_p99_ms", "fast_rank_ms", "fast_latency_ms", "rank_ms",
            "frame_time_ms", "interval_p99_ms", "interval_max_ms", "latency_ms", "speedup",
            "frame_time_ms_lo", "frame_time_ms_hi", "latency_ms_lo", "latency_ms_hi", "confirmed",
            "settled", "pareto", "paced_from", "error")
#: The report's tables: column -> header (the page names no other column).
HEADERS = {"rank": "rank", "label": "option", "gpus": "GPUs", "interval_p99_ms": "p99 interval ms",
           "frame_time_ms": "mean interval ms", "interval_max_ms": "worst interval ms",
           "latency_ms": "latency ms", "speedup": "speedup", "also_on": "tied, also on",
           "frame_time_ms_lo": "mean, band low ms", "frame_time_ms_hi": "mean, band high ms",
           "family": "schedule"}
#: What one advice is in its folder, the report last (the order they are moved into place).
OUTPUTS = ("advice.csv", "advice.json", "pareto.png", "timelines", "report.html")
#: The folder inside OUT that a run writes its advice into before moving it into place.
STAGING = ".advice-partial"


def discard_stale(out: Path) -> None:
    """Remove an earlier advice from `out`, the report first, and a killed run's staging
    folder. Why before the search: a run killed after this leaves no report at all, where an
    old one would read as the answer for the new frame. Other files in `out` stay."""
    for name in (OUTPUTS[-1], *OUTPUTS[:-1], STAGING):
        _remove(out / name)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def write_advice(advice: Advice, out: Path, experiment: str, timelines: int = 3,
                 progress: Progress | None = None, workers: int | Workers | None = None,
                 alongside: Callable[[], object] | None = None) -> dict[str, Path]:
    """Everything in `out` (see the module doc); `experiment` is how the user named it.
    `progress(stage, done, total)`: the timelines drawn so far. `workers`: where the timelines
    are drawn (a count, default the search's, or a command's :class:`Workers`). `alongside`:
    work done while they are drawn, before the answer is written (the command checks the
    assumed shares then, on the same workers: the timelines need only the ranking)."""
    out.mkdir(parents=True, exist_ok=True)
    discard_stale(out)
    staging = out / STAGING
    staging.mkdir()
    with workers_of(workers if workers is not None else
                    min(int(advice.counts.get("workers", 1)), 1 + max(timelines, 0))) as pool:
        files = _write_set(advice, staging, experiment, Timelines(advice, staging / "timelines", timelines, pool,
                                                                  progress), alongside)
    for name in OUTPUTS:  # the report last: until it is there, the folder has no answer
        if (staging / name).exists():
            os.replace(staging / name, out / name)
    staging.rmdir()
    return {key: out / path.relative_to(staging) for key, path in files.items()}


def _write_set(advice: Advice, out: Path, experiment: str, drawn: Timelines,
               alongside: Callable[[], object] | None) -> dict[str, Path]:
    """The advice's files in `out` (the staging folder), while the workers draw the timelines."""
    table = advice.table.reset_index()
    table["command"] = [option_command(experiment, advice.overrides(i)) for i in table["option"]]
    files = {"table": write_table(table[["option", *[c for c in _COLUMNS if c in table], "command"]],
                                  out / "advice.csv")}
    plotted = advice.table.assign(frame_time_ms=advice.table["rank_ms"],
                                  fast_frame_time_ms=advice.table["fast_rank_ms"])
    files["pareto"] = pareto_png(plotted, out / "pareto.png",
                                 f"{Path(experiment).stem}: {advice.counts['options']} options; x: the p99 "
                                 "interval between presents (ms)")
    if alongside is not None:
        alongside()
    shown = drawn.shown()
    files["answer"] = write_json(answer(advice, table, shown), out / "advice.json")
    files["report"] = write_page(out / "report.html", f"mgpusim advise: {Path(experiment).stem}",
                                 sections(advice, table, shown, experiment),
                                 f"experiment {experiment}; every number is simulated (docs/fidelity.md)")
    return files


def answer(advice: Advice, table: pd.DataFrame, shown: list[dict[str, Any]]) -> dict[str, Any]:
    """advice.json: the best option, the fewest GPUs near it, the front, the baseline, the search."""
    ranked = table[table["confirmed"]].sort_values("order")
    keep = [c for c in _COLUMNS if c in table and c not in ("confirmed", "error")] + ["command"]
    best = ranked.iloc[0]
    fewest = _fewest(ranked)
    return {"experiment": advice.experiment, "ranked_by": RANK_MEASURE, "tie_share": TIE,
            "baseline": advice.baseline, "best": best[keep].to_dict(),
            "best_by_mean": _by_mean(ranked)[keep].to_dict(),
            "fewest_gpus_near_best": fewest[keep].to_dict(), "near_best_share": NEAR_BEST,
            "pareto_front": _rows(ranked[ranked["pareto"]])[keep].to_dict("records"),
            "analytic_is_bound": advice.analytic_bound, "open": advice.open,
            "timings_s": advice.timings, "counts": advice.counts, "notes": advice.notes,
            "assumptions": advice.assumptions, "timelines": shown}


def _rows(ranked: pd.DataFrame) -> pd.DataFrame:
    """One option per row of the ranking (ties of one schedule over several links collapsed:
    the cheapest link's stands for them)."""
    return ranked.drop_duplicates("rank", keep="first")


def _fewest(ranked: pd.DataFrame) -> pd.Series:
    best = ranked.iloc[0]
    near = ranked[ranked["rank_ms"] <= best["rank_ms"] * (1 + NEAR_BEST)]
    return near.sort_values(["gpus", "order"], kind="stable").iloc[0]


def _by_mean(ranked: pd.DataFrame) -> pd.Series:
    """The option mean frame time alone would put first (the order's first among equals)."""
    return ranked.sort_values(["frame_time_ms", "order"], kind="stable").iloc[0]


class Timelines:
    """The baseline and the `count` best rows at full fidelity with their traces, handed to
    the workers (drawing a timeline costs more than simulating it; each goes to a folder of
    its own under `root`, so the files are those one process writes); :meth:`shown` waits
    for them. Only the options the report shows are drawn."""

    def __init__(self, advice: Advice, root: Path, count: int, workers: Workers, progress: Progress | None = None):
        rows = _rows(advice.ranked)
        self.picks = [0] + [int(i) for i in rows.index if i != 0][:count]
        self.labels = [advice.options[index].label for index in self.picks]
        self.root = root
        self.folders = [root / f"{k}_{_slug(label)}" for k, label in enumerate(self.labels)]
        self.tally = Tally(progress, "timelines", len(self.picks))
        # the most GPUs first (their timelines have the most rows to draw), so that the
        # workers end about together
        order = sorted(range(len(self.picks)), key=lambda k: -advice.options[self.picks[k]].gpus)
        tasks: dict[int, Future] = {}
        for k in order:
            tasks[k] = workers.submit(_timeline, advice.experiment, advice.overrides(self.picks[k]),
                                      self.labels[k], self.folders[k])
            self.tally.add(tasks[k], 1)
        self.tasks = [tasks[k] for k in range(len(self.picks))]

    def shown(self) -> list[dict[str, Any]]:
        """Each timeline drawn: its option, label, folder, picture and Perfetto trace."""
        self.tally.wait(self.tasks)
        top = self.root.parent
        return [{"option": index, "label": label, "folder": folder.relative_to(top).as_posix(),
                 "timeline": files["timeline"].relative_to(top).as_posix(),
                 "perfetto": files["perfetto"].relative_to(top).as_posix()}
                for index, label, folder, files in zip(self.picks, self.labels, self.folders,
                                                       (task.result() for task in self.tasks))]


def _timeline(experiment: str, overrides: dict[str, Any], label: str, folder: Path) -> dict[str, Path]:
    """One option simulated at full fidelity and its result folder written (in a worker)."""
    return write_result(simulate(load_experiment(experiment, overrides), fidelity="full"), folder, title=label)


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:60]


def _shown(df: pd.DataFrame, cols: list[str]) -> pd.DataFrame:
    return df[cols].rename(columns=HEADERS)


def _pacing(row: pd.Series) -> str:
    return (f"p99 interval {row['interval_p99_ms']:.3f} ms, mean {row['frame_time_ms']:.3f} ms, "
            f"worst {row['interval_max_ms']:.3f} ms")


def sections(advice: Advice, table: pd.DataFrame, shown: list[dict[str, Any]],
             experiment: str) -> list[Section]:
    ranked = table[table["confirmed"]].sort_values("order")
    rows = _rows(ranked)
    best = ranked.iloc[0]
    base = advice.baseline
    fewest = _fewest(ranked)
    text = [f"Ranked by {RANK_MEASURE}, from each option's simulated frames: an option that "
            "presents several frames at once and then waits ranks by the wait.",
            f"Best: {best['label']}: {_pacing(best)} ({1000 / best['rank_ms']:.1f} fps at the 99th "
            f"percentile), latency {best['latency_ms']:.3f} ms, {best['speedup']:.2f}x one GPU "
            f"({_pacing(pd.Series(base))}, latency {base['latency_ms']:.3f} ms)." + _band(best),
            f"Fewest GPUs within {NEAR_BEST:.0%} of that measure: {fewest['label']}: {_pacing(fewest)}, "
            f"latency {fewest['latency_ms']:.3f} ms."]
    by_mean = _by_mean(ranked)
    if by_mean["rank"] != best["rank"]:
        text.append(f"By mean frame time alone the best would be {by_mean['label']} (mean "
                    f"{by_mean['frame_time_ms']:.3f} ms), but its presents are uneven: p99 interval "
                    f"{by_mean['interval_p99_ms']:.3f} ms, worst {by_mean['interval_max_ms']:.3f} ms "
                    f"(rank {by_mean['rank']}).")
    if advice.counts.get("paced"):
        text.append(f"\"{PACED}\": AFR with each present held to an even cadence (schedule.pace_us, "
                    "simulated only), as engines pace AFR; the cadence is the unpaced option's mean "
                    "interval or " + ", ".join(f"{m:.0%}" for m in PACE_MARGINS[1:])
                    + " above it, whichever ranks best.")
    if advice.analytic_bound:
        text.append("The analytic level is an optimistic bound on this profile: "
                    + ("every option whose analytic mean frame time is below the best confirmed measure "
                       "was confirmed, so none of the others is better." if advice.open == 0 else
                       f"{advice.open} option(s) whose analytic mean frame time is below the best "
                       "confirmed measure were not confirmed (raise --confirm): one of them may be better."))
    text += advice.notes
    cols = ["rank", "label", "gpus", "interval_p99_ms", "frame_time_ms", "interval_max_ms", "latency_ms",
            "speedup"]
    band = [c for c in ("frame_time_ms_lo", "frame_time_ms_hi") if c in table and table[c].notna().any()]
    tied = ["also_on"] if rows["also_on"].fillna("").astype(bool).any() else []
    per_gpus = rows.groupby("gpus", sort=True).head(1).sort_values("gpus")
    per_family = rows.groupby("family", sort=False).head(1)
    tie_words = (f"Options within {TIE:.0%} of each other tie (the model's own timeline error: "
                 "docs/advise.md); a tie is ordered by latency, then fewer GPUs, then the cheaper link, "
                 "and one schedule's ties over several links are one row, under the cheapest link"
                 + (f" (\"{HEADERS['also_on']}\": the others)" if tied else "") + ".")
    band_words = (f" \"{HEADERS['frame_time_ms_lo']}\" / \"{HEADERS['frame_time_ms_hi']}\": the mean "
                  "with every pass cost one calibration standard error lower / higher." if band else "")
    out = [Section("Answer", text=text + sensitivity_lines(advice, best))]
    if advice.assumptions.get("passes"):
        out.append(assumptions_section(advice))
    out.append(Section("Pareto front: the ranking measure against latency", tables=[(
        "No other confirmed option has both a shorter p99 interval and a shorter latency "
        f"(differences under {TIE:.0%} are ties)." + band_words,
        _shown(_rows(ranked[ranked["pareto"]]), cols + tied + band))],
        images=[("pareto.png", "every option's p99 interval (the mean where larger) against latency: "
                               "grey at the analytic level, coloured where confirmed at full fidelity")]))
    out.append(Section("Ranking", tables=[(f"Confirmed options, best first; the first 25 rows. {tie_words}"
                                           + band_words, _shown(rows, cols + tied + band).head(25))]))
    out.append(Section("Best of each schedule and each GPU count", tables=[
        ("By schedule (its best confirmed option):", _shown(per_family, cols + ["family"])),
        ("By GPU count:", _shown(per_gpus, cols))]))
    timeline = Section("Timelines", text=["The one-GPU baseline and the best options, simulated at "
                                          "full fidelity (their last four frames). The Perfetto "
                                          "traces open in https://ui.perfetto.dev (Open trace file)."])
    for item in shown:
        timeline.images.append((item["timeline"], item["label"]))
        timeline.links.append((item["perfetto"], f"Perfetto trace: {item['label']}"))
    out.append(timeline)
    commands = [option_command(experiment, advice.overrides(int(i))) for i in rows["option"].head(3)]
    out.append(Section("Run them yourself", text=["Each option is the experiment with overrides:"],
                       code=commands))
    search = pd.DataFrame([{"options": advice.counts["options"], "failed": advice.counts["failed"],
                            "confirmed at full": advice.counts["confirmed"],
                            **{k: round(v, 2) for k, v in advice.timings.items()},
                            "workers": advice.counts["workers"]}])
    families = table.groupby("family", sort=False).agg(options=("option", "count"),
                                                        confirmed=("confirmed", "sum"))
    out.append(Section("The search", tables=[("", search), ("options by schedule",
                                                          families.reset_index())],
                       links=[("advice.csv", "every option (CSV)"), ("advice.json", "the answer (JSON)")]))
    return out


def sensitivity_lines(advice: Advice, best: pd.Series) -> list[str]:
    """How the best option moves with the assumed pixel shares off (one sentence each way)."""
    checked = advice.assumptions
    if not checked.get("passes"):
        return []
    assumed = checked["assumed"]
    if not assumed:
        return ["Every pass's pixel share was stated in the capture: none was assumed."]
    lines = [f"{len(assumed)} of {len(checked['passes'])} passes' pixel shares were assumed, not stated "
             "in the capture (\"Assumptions\" lists them and how each was found)."]
    for shift in checked["shifts"]:
        way = f"{abs(shift['delta']):g} {'lower' if shift['delta'] < 0 else 'higher'}"
        head = (f"With every assumed share {way} (clamped to 0-1; {shift['options']} options re-run at "
                "full fidelity: the best of each schedule and GPU count and the ranking's first rows): ")
        moved = [f"{family}'s best {m['now_ms']:.3f} -> {m['shifted_ms']:.3f} ms"
                 for family, m in shift["families"].items()
                 if abs(m["shifted_ms"] / m["now_ms"] - 1) > TIE]
        moved_words = (" (" + "; ".join(moved) + ")") if moved else " (no schedule's best moves by more than a tie)"
        if shift["same"]:
            lines.append(head + f"the best stays {best['label']}, p99 interval "
                         + (f"{shift['best_rank_ms']:.3f} ms" if abs(shift["best_rank_ms"] / best["rank_ms"] - 1) > 1e-9
                            else "unchanged") + moved_words + ".")
            continue
        today = (f"; today's best would take {shift['today_best_rank_ms']:.3f} ms (row "
                 f"{shift['today_best_rank']})" if shift["today_best_rank_ms"] is not None else "")
        lines.append(head + f"the best would be {shift['best']} (p99 interval {shift['best_rank_ms']:.3f} ms, "
                     f"latency {shift['best_latency_ms']:.3f} ms){today}" + moved_words + ".")
    return lines


def assumptions_section(advice: Advice) -> Section:
    """Every captured pass's pixel share, its geometry share and where it came from."""
    listed = pd.DataFrame(advice.assumptions["passes"])
    table = pd.DataFrame({"pass": listed["pass"], "pixel share": listed["pixel_share"],
                          "geometry share": listed["geometry_share"], "from": listed["source"],
                          "how": listed["why"]})
    return Section("Assumptions: each pass's pixel share", text=[
        "A pass's pixel share is the part of its time that scales with the pixels it draws (a sort-first "
        "tile draws fewer); the rest, its geometry share, scales with the geometry it draws (a sort-last "
        "GPU draws less), and every sort-first GPU repeats it in full. `mgpusim frame import` takes it "
        "from the capture, else from --pixel-share, else infers it from the pass's name, the targets it "
        "writes and what it reads (docs/frame_captures.md, \"Pixel shares\"), and records which in the "
        "experiment file; the answer's sensitivity to the assumed ones is above."],
        tables=[("", table)])


def _band(row: pd.Series) -> str:
    if "frame_time_ms_lo" not in row or pd.isna(row.get("frame_time_ms_lo")):
        return ""
    return (f" Calibration band of its mean (pass costs +-1 standard error): {row['frame_time_ms_lo']:.3f}-"
            f"{row['frame_time_ms_hi']:.3f} ms.")
