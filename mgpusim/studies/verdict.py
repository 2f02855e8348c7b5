"""A study's verdict: the replay level against its target first, then the prediction level
with its confidence band, and the exit status that `mgpusim main`, `study run` and `study
validate` all return.

**Which half.** The verdict is on the held-out half where the command compared one (runs the
calibration never saw), else on the calibration half.

**The replay is the headline.** The replay is the model's timeline with each task at the
duration the run measured for it: a slower machine stretches the measured durations and the
replay with them, so its error is the timeline's own. Its median and worst |frame-time error|
are held against the study's replay target as they are.

**The prediction comes with a band.** The prediction (the calibrated cost model; on a lavapipe
job each run at its own probed speed, `normalized_frame_time_error`, else the raw error) is
compared with a measured side that a noisy machine moves, so each configuration's error `e`
gets an interval from two things the job measured about that run:

  * the speed probes just before and after it (:mod:`mgpusim.measure.speed_norm`): the
    prediction is simulated at the faster probe; the compared window may have run at any speed
    between the two, and a simulated frame scales at most in proportion to the speed, so the
    prediction may be up to `d = slower / faster - 1` (`probe_disagreement`) slower:
    `hi = (1 + e) (1 + d) - 1`;
  * the interleaved repeats: the measured side is their steady window, the fast end of the
    repeats, and the whole repeats' frame times spread by `s = slowest / fastest - 1`
    (`run_to_run_spread`); had the window come from the slower end the measured frame would be
    up to `1 + s` times longer: `lo = (1 + e) / (1 + s) - 1`.

A run without probes (real GPUs, a job before the per-run probes) has `d = 0`; one without
repeats `s = 0`. Then |e| lies in [0, max(|lo|, |hi|)] where `lo <= 0 <= hi`, else in
[min(|lo|, |hi|), max(|lo|, |hi|)]; the median and the worst are monotone in every element, so
the half's median |error| lies between the median of the low ends and the median of the high
ends, and its worst between their maxima. That is the band. The prediction **met** its target
when both high ends are within it, **missed** it when a low end is over it, and is
**undecided** otherwise: the band is wider than the target lets through, and the verdict says
so in those words instead of refusing.

**Exit status** (:func:`exit_status`): 0 a verdict was given and every target set is met; 1 a
verdict was given and a target was missed or could not be shown met (an undecided band); 2 bad
input (the command line, a study, profile or runs folder; before any work); 3 nothing could be
measured or compared (no Vulkan device or driver, a failing Vulkan call, `--steady-check`
finding the machine moving, or no configuration with a measured run).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import pandas as pd

from mgpusim.studies.study_file import Target, Targets

#: Exit statuses (see the module doc).
MET, MISSED, BAD_INPUT, NOT_MEASURED = 0, 1, 2, 3
#: The halves, in the order the verdict prefers them (the held-out one first).
HELD_OUT_TITLE = "Held-out runs (never seen by the fit)"
CALIBRATION_TITLE = "Calibration runs (seen by the fit)"
#: The file beside errors.json with the job's verdict line and exit status.
FILE = "verdict.json"


def prediction_errors(table: pd.DataFrame) -> tuple[pd.Series, str]:
    """Each configuration's prediction error as the verdict judges it: speed-normalized where
    the run was probed, else raw; and which of the two ("speed-normalized", "raw", "mixed")."""
    raw = table["frame_time_error"].astype(float)
    if "normalized_frame_time_error" not in table:
        return raw, "raw"
    norm = pd.to_numeric(table["normalized_frame_time_error"], errors="coerce")
    if norm.isna().all():
        return raw, "raw"
    return norm.fillna(raw), "speed-normalized" if norm.notna().all() else "mixed"


def band(table: pd.DataFrame) -> pd.DataFrame:
    """Per configuration (the table's rows): the prediction error `error`, its interval
    [`lo`, `hi`] and the interval of its magnitude [`abs_lo`, `abs_hi`] (see the module doc)."""
    e, _ = prediction_errors(table)
    d = _column(table, "probe_disagreement")
    s = _column(table, "run_to_run_spread")
    lo = (1 + e) / (1 + s) - 1
    hi = (1 + e) * (1 + d) - 1
    straddles = (lo <= 0) & (hi >= 0)
    abs_lo = np.where(straddles, 0.0, np.minimum(lo.abs(), hi.abs()))
    abs_hi = np.maximum(lo.abs(), hi.abs())
    return pd.DataFrame({"error": e, "lo": lo, "hi": hi, "abs_lo": abs_lo, "abs_hi": abs_hi},
                        index=table.index)


def _column(table: pd.DataFrame, name: str) -> pd.Series:
    """A non-negative fraction column, 0 where absent or unknown."""
    if name not in table:
        return pd.Series(0.0, index=table.index)
    return pd.to_numeric(table[name], errors="coerce").fillna(0.0).clip(lower=0.0)


def half_verdict(table: pd.DataFrame, targets: Targets) -> dict[str, Any]:
    """The verdict of one group of configurations (a half, or a schedule within it): the
    replay's median and worst |frame-time error| against its target, the prediction's with the
    band, each level's status, and the group's (`met`, `missed`, `undecided`, `no target`)."""
    out: dict[str, Any] = {"configurations": int(len(table))}
    rep = pd.to_numeric(table.get("replay_frame_time_error", pd.Series(dtype=float)),
                        errors="coerce").abs()
    if len(rep) and rep.notna().all():
        median, worst = float(rep.median()), float(rep.max())
        out["replay"] = {"median": median, "worst": worst, **_judged(targets.replay, median, worst)}
    else:
        out["replay"] = {"status": "not compared"}
    b = band(table)
    _, kind = prediction_errors(table)
    median, worst = float(b["error"].abs().median()), float(b["error"].abs().max())
    lo = (float(np.median(b["abs_lo"])), float(b["abs_lo"].max()))
    hi = (float(np.median(b["abs_hi"])), float(b["abs_hi"].max()))
    pred: dict[str, Any] = {"errors": kind, "median": median, "worst": worst,
                            "band": {"median": [lo[0], hi[0]], "worst": [lo[1], hi[1]]}}
    if "speed_flag" in table:
        pred["flagged_runs"] = int((table["speed_flag"].fillna("").astype(str) != "").sum())
    target = targets.prediction
    if target is None:
        pred["status"] = "no target"
    else:
        pred["target"] = {"median": target.median, "worst": target.worst}
        if hi[0] <= target.median and hi[1] <= target.worst:
            pred["status"] = "met"
        elif lo[0] > target.median or lo[1] > target.worst:
            pred["status"] = "missed"
        else:
            pred["status"] = "undecided"
    out["prediction"] = pred
    out["status"] = _overall([out["replay"]["status"], pred["status"]])
    return out


def _judged(target: Target | None, median: float, worst: float) -> dict[str, Any]:
    if target is None:
        return {"status": "no target"}
    met = median <= target.median and worst <= target.worst
    return {"target": {"median": target.median, "worst": target.worst}, "status": "met" if met else "missed"}


def _overall(statuses: list[str]) -> str:
    judged = [s for s in statuses if s in ("met", "missed", "undecided")]
    if not judged:
        return "no target"
    if "missed" in judged:
        return "missed"
    return "undecided" if "undecided" in judged else "met"


def chosen_half(stats: Mapping[str, Any]) -> str | None:
    """The half the job's verdict is on: held out where compared, else calibration (None:
    neither was compared)."""
    for title in (HELD_OUT_TITLE, CALIBRATION_TITLE):
        st = stats.get(title)
        if isinstance(st, Mapping) and isinstance(st.get("verdict"), Mapping):
            return title
    return None


def exit_status(stats: Mapping[str, Any]) -> int:
    """The command's exit status from errors.json's halves (see the module doc)."""
    title = chosen_half(stats)
    if title is None:
        return NOT_MEASURED
    return MET if stats[title]["verdict"]["status"] in ("met", "no target") else MISSED


def verdict_line(stats: Mapping[str, Any]) -> str:
    """The job's verdict in one line (report.md's first line, the commands' last)."""
    return " ".join(verdict_parts(stats))


def verdict_parts(stats: Mapping[str, Any]) -> tuple[str, str]:
    """The verdict's first sentence (which half, and whether its targets were met) and the rest
    (the replay level, then the prediction with its band)."""
    title = chosen_half(stats)
    if title is None:
        return "No verdict: no configuration had a measured run to compare.", ""
    v = stats[title]["verdict"]
    half = "held-out" if title == HELD_OUT_TITLE else "calibration"
    head = {"met": "every target met", "missed": "a target missed",
            "undecided": "a target not shown met", "no target": "no target set"}[v["status"]]
    n = v["configurations"]
    return (f"Verdict on the {n} {half} configuration{'s' if n != 1 else ''}: {head}.",
            f"{replay_words(v['replay'])} {prediction_words(v['prediction'])}")


def replay_words(rep: Mapping[str, Any]) -> str:
    """The replay level in one sentence."""
    if rep["status"] == "not compared":
        return "Replay: not compared (the runs have no per-task timestamps)."
    text = (f"Replay (the timeline on the runs' own task durations, which the machine's speed "
            f"cannot move): median {rep['median']:.1%}, worst {rep['worst']:.1%}")
    return text + _against(rep) + "."


def prediction_words(pred: Mapping[str, Any]) -> str:
    """The prediction level with its band in one sentence, saying plainly when the band is
    too wide to judge."""
    b = pred["band"]
    text = (f"Prediction ({pred['errors']}): median {pred['median']:.1%} (band "
            f"{b['median'][0]:.1%}-{b['median'][1]:.1%}), worst {pred['worst']:.1%} (band "
            f"{b['worst'][0]:.1%}-{b['worst'][1]:.1%})")
    text += _against(pred)
    if pred["status"] == "undecided":
        text += (": the band, from the runs' speed probes and repeats, is wider than the target "
                 "lets through, so this job cannot tell; run it again on a quieter machine")
    if pred.get("flagged_runs"):
        text += f" ({pred['flagged_runs']} runs speed-flagged)"
    return text + "."


def _against(level: Mapping[str, Any]) -> str:
    target = level.get("target")
    if target is None:
        return ", no target set"
    return f", target {_pct(target['median'])} / {_pct(target['worst'])}: {level['status']}"


def _pct(fraction: float) -> str:
    """A target as written in the study file: 0.01 -> '1%', 0.025 -> '2.5%'."""
    return f"{fraction * 100:g}%"
