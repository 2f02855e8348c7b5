"""The folder `mgpusim advise` writes: the options table, the answer as JSON, the Pareto plot,
timelines and Perfetto traces of the best options, and one static HTML page over them all.

    OUT/advice.csv      every option: schedule, GPUs, link, analytic and full results, rank
    OUT/advice.json     the answer: best, Pareto front, baseline, how the search went
    OUT/pareto.png      frame time against latency of every option
    OUT/timelines/K_*/  the one-GPU baseline and the best options simulated at full fidelity
                        (summary.json, trace.parquet, timeline.png, trace.perfetto.json)
    OUT/report.html     the page (docs/outputs.md, "Advice")
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pandas as pd

from mgpusim.advise.advisor import Advice, option_command
from mgpusim.io.plot import pareto_png
from mgpusim.io.report_page import Section, write_page
from mgpusim.io.writers import write_json, write_result, write_table
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

#: Options within this share of the best frame time count as as fast (the answer then names
#: the one with the fewest GPUs among them too).
NEAR_BEST = 0.05
_COLUMNS = ("rank", "label", "family", "gpus", "link", "settings", "fast_frame_time_ms",
            "fast_latency_ms", "frame_time_ms", "latency_ms", "speedup", "frame_time_ms_lo",
            "frame_time_ms_hi", "latency_ms_lo", "latency_ms_hi", "confirmed", "settled", "pareto", "error")


def write_advice(advice: Advice, out: Path, experiment: str, timelines: int = 3) -> dict[str, Path]:
    """Everything in `out` (see the module doc); `experiment` is how the user named it."""
    out.mkdir(parents=True, exist_ok=True)
    table = advice.table.reset_index()
    table["command"] = [option_command(experiment, advice.overrides(i)) for i in table["option"]]
    files = {"table": write_table(table[["option", *[c for c in _COLUMNS if c in table], "command"]],
                                  out / "advice.csv")}
    files["pareto"] = pareto_png(advice.table, out / "pareto.png",
                                 f"{Path(experiment).stem}: {advice.counts['options']} options")
    shown = _timelines(advice, out / "timelines", timelines)
    files["answer"] = write_json(answer(advice, table, shown), out / "advice.json")
    files["report"] = write_page(out / "report.html", f"mgpusim advise: {Path(experiment).stem}",
                                 sections(advice, table, shown, experiment),
                                 f"experiment {experiment}; every number is simulated (docs/fidelity.md)")
    return files


def answer(advice: Advice, table: pd.DataFrame, shown: list[dict[str, Any]]) -> dict[str, Any]:
    """advice.json: the best option, the fewest GPUs near it, the front, the baseline, the search."""
    ranked = table[table["confirmed"]].sort_values("rank")
    keep = [c for c in _COLUMNS if c in table and c not in ("confirmed", "error")] + ["command"]
    best = ranked.iloc[0]
    near = ranked[ranked["frame_time_ms"] <= best["frame_time_ms"] * (1 + NEAR_BEST)]
    fewest = near.sort_values(["gpus", "frame_time_ms"]).iloc[0]
    return {"experiment": advice.experiment, "baseline": advice.baseline,
            "best": best[keep].to_dict(), "fewest_gpus_near_best": fewest[keep].to_dict(),
            "near_best_share": NEAR_BEST,
            "pareto_front": ranked[ranked["pareto"]][keep].to_dict("records"),
            "analytic_is_bound": advice.analytic_bound, "open": advice.open,
            "timings_s": advice.timings, "counts": advice.counts, "notes": advice.notes,
            "timelines": shown}


def _timelines(advice: Advice, root: Path, count: int) -> list[dict[str, Any]]:
    """The baseline and the `count` best options at full fidelity with their traces."""
    ranked = advice.ranked
    picks = [0] + [int(i) for i in ranked.index if i != 0][:count]
    out = []
    for k, index in enumerate(picks):
        option = advice.options[index]
        exp = load_experiment(advice.experiment, advice.overrides(index))
        result = simulate(exp, fidelity="full")
        folder = root / f"{k}_{_slug(option.label)}"
        files = write_result(result, folder, title=option.label)
        out.append({"option": index, "label": option.label, "folder": folder.relative_to(root.parent).as_posix(),
                    "timeline": files["timeline"].relative_to(root.parent).as_posix(),
                    "perfetto": files["perfetto"].relative_to(root.parent).as_posix()})
    return out


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:60]


def sections(advice: Advice, table: pd.DataFrame, shown: list[dict[str, Any]],
             experiment: str) -> list[Section]:
    ranked = table[table["confirmed"]].sort_values("rank")
    best = ranked.iloc[0]
    base = advice.baseline
    near = ranked[ranked["frame_time_ms"] <= best["frame_time_ms"] * (1 + NEAR_BEST)]
    fewest = near.sort_values(["gpus", "frame_time_ms"]).iloc[0]
    text = [f"Best: {best['label']}: frame time {best['frame_time_ms']:.3f} ms "
            f"({1000 / best['frame_time_ms']:.1f} fps), latency {best['latency_ms']:.3f} ms, "
            f"{best['speedup']:.2f}x the frame rate of one GPU ({base['frame_time_ms']:.3f} ms, "
            f"latency {base['latency_ms']:.3f} ms)." + _band(best),
            f"Fewest GPUs within {NEAR_BEST:.0%} of that frame time: {fewest['label']}: "
            f"{fewest['frame_time_ms']:.3f} ms, latency {fewest['latency_ms']:.3f} ms."]
    if advice.analytic_bound:
        text.append("The analytic level is an optimistic bound on this profile: "
                    + ("every option it puts below the best confirmed frame time was confirmed, so "
                       "none of the others is faster." if advice.open == 0 else
                       f"{advice.open} option(s) it puts below the best confirmed frame time were not "
                       "confirmed (raise --confirm): one of them may be faster."))
    text += advice.notes
    cols = ["rank", "label", "gpus", "frame_time_ms", "latency_ms", "speedup"]
    band = [c for c in ("frame_time_ms_lo", "frame_time_ms_hi") if c in table and table[c].notna().any()]
    per_gpus = ranked.groupby("gpus", sort=True).head(1).sort_values("gpus")
    per_family = ranked.groupby("family", sort=False).head(1)
    out = [Section("Answer", text=text),
           Section("Pareto front: frame time against latency", tables=[(
               "No other confirmed option has both a shorter frame time and a shorter latency; "
               "_lo/_hi: every pass cost one calibration standard error lower/higher (where the "
               "profile has them).", ranked[ranked["pareto"]][cols + band])],
               images=[("pareto.png", "every option: grey at the analytic level, coloured where "
                                      "confirmed at full fidelity")]),
           Section("Ranking", tables=[("Confirmed options, best first (frame time, then latency, "
                                       "then GPUs); the first 25.", ranked[cols + band].head(25))]),
           Section("Best of each schedule and each GPU count", tables=[
               ("By schedule (its best confirmed option):", per_family[cols + ["family"]]),
               ("By GPU count:", per_gpus[cols])])]
    timeline = Section("Timelines", text=["The one-GPU baseline and the best options, simulated at "
                                          "full fidelity (their last four frames). The Perfetto "
                                          "traces open in https://ui.perfetto.dev (Open trace file)."])
    for item in shown:
        timeline.images.append((item["timeline"], item["label"]))
        timeline.links.append((item["perfetto"], f"Perfetto trace: {item['label']}"))
    out.append(timeline)
    commands = [option_command(experiment, advice.overrides(int(i)))
                for i in ranked["option"].head(3)]
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


def _band(row: pd.Series) -> str:
    if "frame_time_ms_lo" not in row or pd.isna(row.get("frame_time_ms_lo")):
        return ""
    return (f" Calibration band (pass costs +-1 standard error): {row['frame_time_ms_lo']:.3f}-"
            f"{row['frame_time_ms_hi']:.3f} ms.")
