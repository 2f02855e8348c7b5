"""report.html of `mgpusim study validate|run`: the study's errors as a static page.

Why beside report.md: the Markdown report names its pictures but shows them only where a
Markdown viewer renders it; the page (the report page code `mgpusim advise` uses,
mgpusim/io/report_page.py) shows per half and per schedule the error table, an error plot, the
measured-above-simulated timelines, and links each configuration's Perfetto traces, opened from
the file in any browser, offline.

    OUT/report.html             the page
    OUT/errors_<half>.png       frame-time errors per configuration, prediction and replay
    OUT/validation/<config>/    timelines.png, measured/simulated.perfetto.json (linked)
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence, cast

import pandas as pd

from mgpusim.io.plot import errors_png
from mgpusim.io.report_page import Section, write_page

#: The error table's columns on the page: (column, heading, scale). Errors are shown in %.
_COLUMNS = (("config", "config", 1), ("measured_frame_ms", "measured frame (ms)", 1),
            ("simulated_frame_ms", "simulated frame (ms)", 1), ("frame_time_error", "error %", 100),
            ("replay_frame_time_error", "replay error %", 100), ("run_to_run_spread", "spread %", 100),
            ("measured_latency_ms", "measured latency (ms)", 1),
            ("simulated_latency_ms", "simulated latency (ms)", 1), ("latency_error", "latency error %", 100),
            ("replay_latency_error", "replay latency error %", 100),
            ("step_most_off", "step most off", 1), ("step_difference_ms", "its difference (ms)", 1),
            ("wait_most_off", "hand-off most off", 1), ("wait_difference_ms", "its wait difference (ms)", 1),
            ("probe_ratio", "probe ratio (run / calibration)", 1),
            ("normalized_frame_time_error", "normalized error %", 100), ("speed_flag", "speed flag", 1))
INTRO = ("Errors are simulated / measured - 1, at two levels: the prediction (the calibrated cost "
         "model) and the replay (the model's timeline with every task taking the duration the run "
         "measured for it: what is left is the timeline's own error). `spread` is the run-to-run "
         "spread of the measured runs (slowest / fastest - 1), the machine's own noise. Each "
         "timeline shows the measured run above the simulated one.")


def page_table(table: pd.DataFrame) -> pd.DataFrame:
    """The error table as the page shows it: readable headings, errors in %."""
    cols = [(c, head, scale) for c, head, scale in _COLUMNS if c in table]
    return pd.DataFrame({head: table[c] * scale if scale != 1 else table[c] for c, head, scale in cols})


def stats_line(st: Mapping[str, Any]) -> str:
    """A half's or a schedule's error statistics in one sentence (report.md and the page)."""
    line = (f"Prediction: median |frame-time error| {st['median_abs_frame_time_error']:.1%}, worst "
            f"{st['worst_abs_frame_time_error']:.1%} over {st['configurations']} configurations; "
            f"median |latency error| {st['median_abs_latency_error']:.1%}, worst "
            f"{st['worst_abs_latency_error']:.1%}.")
    if "normalized_median_abs_frame_time_error" in st:
        line += " " + normalized_line(st)
    if "replay_median_abs_frame_time_error" in st:
        line += (f" Replay (the timeline on measured durations): frame time "
                 f"{st['replay_median_abs_frame_time_error']:.1%} / "
                 f"{st['replay_worst_abs_frame_time_error']:.1%}, latency "
                 f"{st['replay_median_abs_latency_error']:.1%} / "
                 f"{st['replay_worst_abs_latency_error']:.1%} (median / worst).")
    return line


def normalized_line(st: Mapping[str, Any]) -> str:
    """The speed-normalized errors and the verdict (or its refusal) of one group of runs."""
    v = st["verdict"]
    line = (f"Speed-normalized (each run at its own probe ratio, median "
            f"{st['median_probe_ratio']:.2f}): median |frame-time error| "
            f"{st['normalized_median_abs_frame_time_error']:.1%}, worst "
            f"{st['normalized_worst_abs_frame_time_error']:.1%}.")
    if "refused" in v:
        return line + f" **Refused: {v['refused']}.**"
    return (line + f" Verdict over the {v['trusted_runs']} of {v['runs']} runs the speed rule "
            f"trusts: median |frame-time error| {v['median_abs_frame_time_error']:.1%}.")


def write_study_page(out: Path, name: str, tables: Mapping[str, pd.DataFrame], stats: Mapping[str, Any],
                     by_schedule: Mapping[str, Mapping[str, Any]], fit_text: str,
                     speed_lines: Sequence[str] = (),
                     missing: Mapping[str, list[str]] | None = None) -> Path:
    """OUT/report.html (see the module doc): `stats` per half as errors.json has them,
    `by_schedule` per half and schedule as errors_by_schedule.json has them;
    `speed_lines`: report.md's section on the machine's speed (Markdown, shown as text)."""
    sections = [Section("Summary", text=[INTRO] + [f"{title}: {stats_line(stats[title])}"
                                                    for title in tables if title in stats
                                                    and "configurations" in stats[title]])]
    if speed_lines:
        sections.append(Section("The machine's speed during the job",
                                code=["\n".join(line for line in speed_lines if not line.startswith("## "))]))
    for title, table in tables.items():
        sections += _half(out, title, table, (missing or {}).get(title, []), by_schedule.get(title, {}))
    sections.append(Section("Calibration", code=[fit_text]))
    files = [(f.name, f.name) for f in sorted(out.glob("errors*.json")) + sorted(out.glob("errors_*.csv"))]
    sections.append(Section("Files", links=files + [("report.md", "report.md (the same report in Markdown)")]))
    return write_page(out / "report.html", f"mgpusim study {name}: measured vs simulated", sections,
                      f"{sum(len(t) for t in tables.values())} configurations compared")


def _half(out: Path, title: str, table: pd.DataFrame, absent: list[str],
          schedule_stats: Mapping[str, Any]) -> list[Section]:
    """A half's sections: its error plot, then one per schedule (table, timelines, traces)."""
    head = Section(title)
    if absent:
        head.text.append(f"No measured run, not compared: {', '.join(absent)}.")
    if table.empty:
        return [head]
    plot = out / f"errors_{title.split()[0].lower()}.png"
    errors_png(table, plot, title)
    head.images.append((plot.name, "frame-time error per configuration: prediction and replay"))
    parts = [head]
    groups = table.groupby("schedule", sort=False) if "schedule" in table else [("", table)]
    for schedule, part in groups:
        s = Section(f"{title.split(' (')[0]}: {schedule}", text=[stats_line(schedule_stats[cast(str, schedule)])],
                    tables=[("", page_table(part))])
        for config in part["config"]:
            folder = out / "validation" / str(config)
            if (folder / "timelines.png").exists():
                s.images.append((f"validation/{config}/timelines.png", f"{config}: measured above, simulated below"))
            for side in ("measured", "simulated"):
                if (folder / f"{side}.perfetto.json").exists():
                    s.links.append((f"validation/{config}/{side}.perfetto.json",
                                    f"{config}: {side} trace (Perfetto: https://ui.perfetto.dev, Open trace file)"))
        parts.append(s)
    return parts

