"""report.html of `mgpusim study validate|run` and `mgpusim main`: report.md as a static page.

Why one source: the page is report.md rendered by a Markdown library
(:func:`mgpusim.io.report_page.write_markdown_page`), so the two cannot say different things;
the page shows the pictures report.md names (per half the error plot, per configuration the
measured-above-simulated timelines) and links each configuration's Perfetto traces, opened from
the file in any browser, offline. Its first paragraph is the verdict line.

    OUT/report.html             the page
    OUT/errors_<half>.png       frame-time errors per configuration, prediction and replay
    OUT/validation/<config>/    timelines.png, measured/simulated.perfetto.json (linked)
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from mgpusim.io.report_page import write_markdown_page
from mgpusim.studies.verdict import prediction_words, replay_words


def stats_line(st: Mapping[str, Any]) -> str:
    """A half's or a schedule's errors in a few sentences (report.md and so the page): the
    replay and the prediction with its band against their targets (`verdict`), the raw
    prediction where the verdict's is speed-normalized, and the latency."""
    v = st.get("verdict")
    if v is None:  # a group without a verdict (only errors): the raw figures
        return (f"Prediction: median |frame-time error| {st['median_abs_frame_time_error']:.1%}, worst "
                f"{st['worst_abs_frame_time_error']:.1%} over {st['configurations']} configurations.")
    n = st["configurations"]
    line = f"{n} configuration{'s' if n != 1 else ''}. {replay_words(v['replay'])} {prediction_words(v['prediction'])}"
    if v["prediction"]["errors"] != "raw":
        line += (f" Raw (at the calibration's speed): median {st['median_abs_frame_time_error']:.1%}, "
                 f"worst {st['worst_abs_frame_time_error']:.1%}.")
    line += (f" Latency: prediction {st['median_abs_latency_error']:.1%} / "
             f"{st['worst_abs_latency_error']:.1%}")
    if "replay_median_abs_latency_error" in st:
        line += (f", replay {st['replay_median_abs_latency_error']:.1%} / "
                 f"{st['replay_worst_abs_latency_error']:.1%}")
    return line + " (median / worst)."


def write_study_page(out: Path, markdown: str) -> Path:
    """OUT/report.html from report.md's text (its pictures are already beside it)."""
    return write_markdown_page(out / "report.html", markdown)
