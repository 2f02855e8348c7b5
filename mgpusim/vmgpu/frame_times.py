"""vmgpu's measured frame times beside the model's predictions: a study of a renderer we did not
write (the thesis's own, run on lavapipe by :mod:`mgpusim.vmgpu.campaign`).

Why a study of its own kind: vmgpu gives frame times, not the per-task timestamps our runner
writes, so there is no trace to join and no replay level; what can be compared is each
configuration's frame time, measured (the median over its interleaved repeats, with their range
as the noise band) and predicted by the as-built five-step schedule on the lavapipe profile
calibrated on our own microbenchmarks. The study file names, before any comparison, the
parameters fitted to vmgpu's own frame times, at most one per strategy (`[[fit]]`: a profile
key, the strategy and GPU count whose calibration-half runs set it, fitted in the file's order
with the earlier ones in place); every other number comes from the profile or the sources.

For 3 and 4 GPUs the prediction stands beside an Amdahl line fitted to the same 1 -> 2 GPU
point (the measured single-GPU and 2-GPU frame times of that strategy, triangles and
resolution): a model that cannot beat it has learnt nothing about what each added GPU costs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from mgpusim.io import table_files
from mgpusim.model.errors import InputError
from mgpusim.model.toml_checks import Table, read_toml
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_overrides
from mgpusim.sim.simulation import simulate

#: The value of a study file's `kind` that makes it a frame-time study of an external renderer.
KIND = "external_frame_times"
#: vmgpu's strategy names -> the model's schedules (single is the sort-first path on one GPU:
#: vmgpu's InitSF.cpp renders it straight into the swapchain).
SCHEDULES = {"single": "sort_first", "sort-first": "sort_first", "sort-last": "sort_last"}
#: The columns of a measured runs table this study reads.
RUN_COLUMNS = ("config", "half", "strategy", "gpus", "triangles", "width", "height", "repeat",
               "median_ms", "other_cores")
#: A run is quiet when the machine's other processes used at most this much of a core beside
#: it (on two cores, a quarter of one moves a CPU-bound run by about a tenth).
QUIET_OTHER_CORES = 0.25


@dataclass(frozen=True)
class Fit:
    """A parameter fitted to the renderer's own frame times: `key` (a `--set` key), searched
    in [`low`, `high`] (geometrically) so that the calibration-half runs of `strategy` on
    `gpus` GPUs have a median error of zero; `why` says what it stands for."""

    key: str
    strategy: str
    gpus: int
    low: float
    high: float
    why: str


@dataclass(frozen=True)
class MeasuredCosts:
    """A pass kind's costs fitted on our microbenchmark of the renderer's own draw (a measure
    table's rows where every `where` column holds one of its values), in place of the
    profile's: `why` says what the rows drew. Why: a renderer's draw is not our runner's (its
    mesh, vertex layout, shaders), and measuring it is better than fitting a parameter to the
    renderer's frame times."""

    table: Path
    kind: str
    where: dict[str, tuple[Any, ...]]
    why: str


@dataclass(frozen=True)
class FrameTimeStudy:
    name: str
    description: str
    path: Path
    experiment: Path
    runs: Path
    sets: tuple[str, ...]
    fits: tuple[Fit, ...]
    targets: dict[str, float]
    measured_costs: MeasuredCosts | None = None


def is_frame_time_study(path: Path) -> bool:
    """Whether the study file at `path` is a frame-time study (its `kind`)."""
    return read_toml(path).get("kind") == KIND


def load_study(path: Path) -> FrameTimeStudy:
    """The study file at `path`, every path in it relative to the file."""
    t = Table(read_toml(path), str(path))
    base = path.parent
    t.get("kind", str, choices=(KIND,))
    fits = t.tables("fit") if t.has("fit") else []
    targets = t.table("targets", None)
    costs = t.table("measured_costs") if t.has("measured_costs") else None
    study = FrameTimeStudy(
        name=t.get("name", str), description=t.get("description", str, ""), path=path,
        experiment=base / t.get("experiment", str), runs=base / t.get("runs", str),
        sets=tuple(str(s) for s in t.get("sets", list, [])),
        fits=tuple(_fit(f) for f in fits),
        targets={"median_error": targets.get("median_error", float, 0.05, minimum=0.0),
                 "worst_error": targets.get("worst_error", float, 0.10, minimum=0.0)},
        measured_costs=None if costs is None else _measured_costs(costs, base))
    for table in (t, *fits, targets, *([] if costs is None else [costs])):
        table.finish()
    strategies = [f.strategy for f in study.fits]
    if len(set(strategies)) < len(strategies):
        raise InputError("at most one fitted parameter per strategy", file=str(path), field="fit")
    return study


def _measured_costs(t: Table, base: Path) -> MeasuredCosts:
    where = t.table("where", {})
    chosen = {key: tuple(v if isinstance(v, list) else [v]) for key, v in where.data.items()}
    for key in chosen:
        where.get(key, object)
    where.finish()
    return MeasuredCosts(base / t.get("table", str), t.get("pass", str), chosen, t.get("why", str))


def measured_cost_sets(study: FrameTimeStudy) -> tuple[tuple[str, ...], str]:
    """The `--set` overrides of the study's measured costs (none where it has none) and a line
    that says what was fitted on what, with the fit's residual."""
    from mgpusim.calibration.measure_tables import check_measure_table  # noqa: PLC0415
    from mgpusim.calibration.pass_fit import Calibration, fit_passes  # noqa: PLC0415
    costs = study.measured_costs
    if costs is None:
        return (), ""
    if not costs.table.is_file():
        raise InputError(f"no measure table at {costs.table}", file=str(study.path),
                         field="measured_costs.table")
    rows = check_measure_table(table_files.read_parquet(costs.table), str(costs.table))
    for key, chosen in costs.where.items():
        if key not in rows.columns:
            raise InputError(f"the table has no column {key!r}", file=str(study.path),
                             field=f"measured_costs.where.{key}")
        rows = rows[rows[key].isin(chosen)]
    rows = rows[rows["pass"] == costs.kind].assign(source=costs.table.name)
    cal = Calibration()
    fit_passes(rows, cal)
    if costs.kind not in cal.pass_fits:
        raise InputError(f"no {costs.kind!r} rows on one GPU where {dict(costs.where)}",
                         file=str(study.path), field="measured_costs.where")
    fit = cal.pass_fits[costs.kind]
    coef = dict(zip(fit.names, (float(c) for c in fit.coef)))
    sets = tuple(f"profile.gpus.*.costs.{costs.kind}.{name}={value!r}" for name, value in coef.items())
    shown = ", ".join(f"{name} {value:.4g}" for name, value in coef.items())
    line = (f"Measured, not fitted to the frame times: the {costs.kind} costs of {costs.why}, "
            f"fitted on {len(rows)} rows of {costs.table.name} ({shown}; rms {fit.rel_rms:.1%} of a "
            f"draw), in place of the profile's.")
    return sets, line


def _fit(f: Table) -> Fit:
    fit = Fit(f.get("key", str), f.get("strategy", str, choices=tuple(SCHEDULES)),
              f.get("gpus", int, minimum=1, maximum=4), f.get("low", float, above=0.0),
              f.get("high", float, above=0.0), f.get("why", str))
    if fit.low >= fit.high:
        raise f.error("low", "must be below high")
    if (fit.strategy == "single") != (fit.gpus == 1):
        raise f.error("gpus", "single runs on 1 GPU, sort-first and sort-last on 2 or more")
    return fit


def measured(study: FrameTimeStudy) -> pd.DataFrame:
    """One row per configuration: the median of its repeats' median frame times, and the
    repeats' range as the noise band (`lo_ms`, `hi_ms`); `quiet` counts the repeats measured
    with other processes using at most QUIET_OTHER_CORES (the machine's other load, which no
    model of vmgpu can predict)."""
    runs_file = study.runs / "runs.parquet"
    if not runs_file.is_file():
        raise InputError(f"no measured runs table at {runs_file}", file=str(study.path), field="runs")
    runs = table_files.read_parquet(runs_file)
    missing = [c for c in RUN_COLUMNS if c not in runs.columns]
    if missing:
        raise InputError(f"{runs_file} lacks the columns {missing}", file=str(study.path), field="runs")
    keys = ["config", "half", "strategy", "gpus", "triangles", "width", "height"]
    runs = runs.assign(quiet=runs.other_cores <= QUIET_OTHER_CORES)
    aggregates: dict[str, Any] = {"measured_ms": ("median_ms", "median"), "lo_ms": ("median_ms", "min"),
                                  "hi_ms": ("median_ms", "max"), "repeats": ("repeat", "nunique"),
                                  "quiet": ("quiet", "sum")}
    if "gap_median_ms" in runs.columns:  # the idle time between two frames (Qt's update timer)
        aggregates["gap_ms"] = ("gap_median_ms", "median")
    table = runs.groupby(keys, as_index=False).agg(**aggregates)
    return table.sort_values(["strategy", "triangles", "width", "gpus"]).reset_index(drop=True)


def experiment_of(study: FrameTimeStudy, row: Any, extra: tuple[str, ...] = ()) -> Experiment:
    """The model's experiment for one measured configuration."""
    sets = [*study.sets, f"schedule.name={SCHEDULES[row.strategy]}", f"schedule.gpus={int(row.gpus)}",
            f"scene.width={int(row.width)}", f"scene.height={int(row.height)}",
            f"scene.passes.0.triangles={int(row.triangles)}", *extra]
    return load_experiment(study.experiment, parse_overrides(sets))


def predict(study: FrameTimeStudy, table: pd.DataFrame, values: dict[str, float]) -> pd.Series:
    """The model's frame time (ms) of every row of `table` with the fitted keys at `values`.
    Every fitted key is set on every row, and a strategy reads only its own (a sort-last frame
    has no sort-first composite): unused keys are therefore not refused here."""
    extra = tuple(f"{key}={value!r}" for key, value in values.items())
    return pd.Series([simulate(experiment_of(study, row, extra), record_trace=False,
                               check_unused=False).summary["frame_time_ms"]
                      for row in table.itertuples()], index=table.index)


@dataclass(frozen=True)
class Fitted:
    """A fitted parameter's value; `bound_error`: where no value in the fit's range brings the
    median error to zero, the median error at the bound it stopped at (else None)."""

    value: float
    bound_error: float | None = None


def fit_values(study: FrameTimeStudy, table: pd.DataFrame,
               progress: Callable[[str], None] | None = None) -> dict[str, Fitted]:
    """Every fitted parameter, in the study file's order, each with the earlier ones in place."""
    fitted: dict[str, Fitted] = {}
    for fit in study.fits:
        fitted[fit.key] = fit_value(study, fit, table, values_of(fitted), progress)
    return fitted


def values_of(fitted: dict[str, Fitted]) -> dict[str, float]:
    """The fitted values by key."""
    return {key: f.value for key, f in fitted.items()}


def fit_value(study: FrameTimeStudy, fit: Fit, table: pd.DataFrame, known: dict[str, float],
              progress: Callable[[str], None] | None = None) -> Fitted:
    """One fitted parameter: a geometric bisection on [low, high] until the calibration runs of
    the fit's strategy and GPU count have a median signed error of zero (to 0.1 % of the
    value), the `known` values in place. The frame time must move one way with the value over
    the range (a cost up, a speed down). Where the range holds no such value (the model cannot
    reach the measured frame times with that parameter), the bound with the smaller error,
    marked: the comparison then shows what the model misses instead of stopping."""
    rows = table[(table.half == "calibration") & (table.strategy == fit.strategy) & (table.gpus == fit.gpus)]
    if rows.empty:
        raise InputError(f"no calibration run of {fit.strategy!r} on {fit.gpus} GPU(s) to fit {fit.key}",
                         file=str(study.path), field="fit.strategy")

    def error(value: float) -> float:
        predicted = predict(study, rows, {**known, fit.key: value})
        return float(((predicted - rows.measured_ms) / rows.measured_ms).median())

    low, high = fit.low, fit.high
    e_low, e_high = error(low), error(high)
    if (e_low > 0) == (e_high > 0):
        return Fitted(low, e_low) if abs(e_low) <= abs(e_high) else Fitted(high, e_high)
    rising = e_high > 0  # a cost: the prediction grows with the value
    while high / low > 1.001:
        mid = math.sqrt(low * high)
        if progress:
            progress(f"fit {fit.key} in [{low:.4g}, {high:.4g}]")
        if (error(mid) > 0) == rising:
            high = mid
        else:
            low = mid
    return Fitted(math.sqrt(low * high))


def amdahl_ms(t1: float, t2: float, gpus: int) -> float:
    """The frame time at `gpus` GPUs on the Amdahl line through the 1- and 2-GPU frame times:
    gain(N) = 1 / ((1 - p) + p / N) with p from gain(2) = t1 / t2 (p < 0 where two GPUs are
    slower than one: the line then keeps falling)."""
    p = 2.0 * (1.0 - t2 / t1)
    return t1 * ((1.0 - p) + p / gpus)


def compared(study: FrameTimeStudy, table: pd.DataFrame, values: dict[str, float]) -> pd.DataFrame:
    """`table` with the prediction, its error, the noise band's half-width and, at 3 and 4
    GPUs, the Amdahl line through the same strategy's measured 1 -> 2 GPU point."""
    out = table.assign(predicted_ms=predict(study, table, values))
    out["error"] = out.predicted_ms / out.measured_ms - 1.0
    out["noise"] = (out.hi_ms - out.lo_ms) / 2.0 / out.measured_ms
    single = out[out.strategy == "single"].set_index(["triangles", "width", "height"]).measured_ms
    two = out[out.gpus == 2].set_index(["strategy", "triangles", "width", "height"]).measured_ms
    amdahl: list[float] = []
    for strategy, gpus, *key in zip(out.strategy, out.gpus, out.triangles, out.width, out.height):
        point = (strategy, *key)
        known = tuple(key) in single.index and point in two.index
        amdahl.append(amdahl_ms(float(single[tuple(key)]), float(two[point]), int(gpus))
                      if gpus >= 3 and known else float("nan"))
    out["amdahl_ms"] = amdahl
    out["amdahl_error"] = out.amdahl_ms / out.measured_ms - 1.0
    return out


def _checks(table: pd.DataFrame) -> tuple[pd.Series, pd.DataFrame, pd.Series]:
    """What the targets read on `table` (one half): every row's |error|, the 3- and 4-GPU rows
    with an Amdahl line, and which of those the model predicts closer than the line."""
    abs_err = table.error.abs()
    far = table[table.gpus >= 3].dropna(subset=["amdahl_error"])
    return abs_err, far, far.error.abs() < far.amdahl_error.abs()


def targets_met(study: FrameTimeStudy, table: pd.DataFrame) -> bool:
    """Whether `table` (one half) meets every target: the median and worst |error|, and every
    3- and 4-GPU prediction closer than the Amdahl line through the same 1 -> 2 point."""
    abs_err, _far, beats = _checks(table)
    return bool(abs_err.median() <= study.targets["median_error"] and abs_err.max() <= study.targets["worst_error"]
                and beats.all())


def verdict(study: FrameTimeStudy, table: pd.DataFrame) -> list[str]:
    """Lines that state each target met or missed on `table` (one half)."""
    abs_err, far, beats = _checks(table)
    lines = [f"median |error| {abs_err.median():.1%} (target {study.targets['median_error']:.0%}): "
             f"{'met' if abs_err.median() <= study.targets['median_error'] else 'missed'}",
             f"worst |error| {abs_err.max():.1%} (target {study.targets['worst_error']:.0%}): "
             f"{'met' if abs_err.max() <= study.targets['worst_error'] else 'missed'}"
             f" ({table.config.iloc[int(abs_err.to_numpy().argmax())]})",
             f"3 and 4 GPUs closer than Amdahl's line: {int(beats.sum())} of {len(far)}"
             + ("" if far.empty else f" (model median {far.error.abs().median():.1%}, Amdahl "
                                     f"{far.amdahl_error.abs().median():.1%})"),
             f"noise: the repeats' half-range is {table.noise.median():.1%} of the frame time "
             f"(median), {table.noise.max():.1%} at most; {int((table.quiet == table.repeats).sum())} "
             f"of {len(table)} configurations had every repeat quiet (other processes <= "
             f"{QUIET_OTHER_CORES} core)"]
    return lines


#: The columns of the printed comparison, in order.
SHOWN = ["config", "strategy", "gpus", "triangles", "width", "height", "repeats", "quiet", "measured_ms",
         "lo_ms", "hi_ms", "predicted_ms", "error", "amdahl_ms", "amdahl_error"]


@dataclass(frozen=True)
class Validation:
    """A frame-time study checked: the fitted values (by key) and each half's comparison."""

    study: FrameTimeStudy
    fitted: dict[str, Fitted]
    halves: dict[str, pd.DataFrame]
    #: what the study's measured costs are and where from ("" where it has none)
    measured: str = ""

    @property
    def values(self) -> dict[str, float]:
        """The fitted values by key."""
        return values_of(self.fitted)

    @property
    def met(self) -> bool:
        """Every target met on the verdict's half (the held-out one where it was compared, else
        the calibration half), and every fit found inside its range."""
        return (targets_met(self.study, list(self.halves.values())[-1])
                and all(f.bound_error is None for f in self.fitted.values()))


def validate(study: FrameTimeStudy, held_out: bool,
             progress: Callable[[str], None] | None = None) -> Validation:
    """Fit the study's parameters on the calibration half, then compare the calibration half
    and (`held_out`) the held-out half with the model."""
    table = measured(study)
    sets, line = measured_cost_sets(study)
    study = replace(study, sets=study.sets + sets)
    fitted = fit_values(study, table, progress)
    values = values_of(fitted)
    halves = {"calibration": compared(study, table[table.half == "calibration"], values)}
    if held_out:
        halves["held-out"] = compared(study, table[table.half == "held-out"], values)
    return Validation(study, fitted, halves, line)


def markdown(v: Validation) -> str:
    """The validation as a page: the verdict of each half first, then its table."""
    s = v.study
    lines = [f"# {s.name}: measured vs predicted frame times", "", s.description, "",
             "Named in the study file before any comparison, each fitted on the calibration half "
             "only (in this order, the earlier ones in place):", ""]
    lines += [f"- `{f.key}` = {v.values[f.key]:.4g}{_bound_note(f, v.fitted[f.key])} on the "
              f"{f.strategy} runs on {f.gpus} GPU(s): {f.why}" for f in s.fits] or ["- none"]
    lines += ["", v.measured] if v.measured else []
    lines += ["", "Replay level: none (vmgpu writes no per-task timestamps)."]
    gap = gap_line(v)
    lines += ([gap] if gap else []) + [""]
    for half, table in v.halves.items():
        lines += [f"## {half}", ""] + [f"- {line}" for line in verdict(s, table)] + [""]
        shown = table[SHOWN].copy()
        for col in ("error", "amdahl_error"):
            shown[col] = shown[col].map(lambda x: "" if pd.isna(x) else f"{x:+.1%}")
        for col in ("measured_ms", "lo_ms", "hi_ms", "predicted_ms", "amdahl_ms"):
            shown[col] = shown[col].map(lambda x: "" if pd.isna(x) else f"{x:.2f}")
        lines += [_pipe_table(shown), ""]
    return "\n".join(lines)


def _bound_note(fit: Fit, fitted: Fitted) -> str:
    """What a value stopped at its range's bound says: the model cannot reach the runs with it."""
    if fitted.bound_error is None:
        return ""
    return (f" (its bound: no value in [{fit.low:g}, {fit.high:g}] reaches the measured frame "
            f"times; median error there {fitted.bound_error:+.1%}: a fit missed)")


def gap_line(v: Validation) -> str:
    """The measured idle time between frames beside the model's (the part of a frame no render
    cost moves), or '' when the runs table does not hold it."""
    both = pd.concat(v.halves.values())
    if "gap_ms" not in both.columns:
        return ""
    model_ms = load_experiment(v.study.experiment).schedule.options.get("update_gap_ns", 0) / 1e6
    off = abs(both.gap_ms.median() - model_ms) / both.measured_ms.median()
    where = ("what the model misses is in the frame's busy part" if off < 0.02 else
             f"the gap alone is {off:.0%} of the median frame off")
    return (f"Idle time between two frames (Qt's update timer and its event loop): measured "
            f"{both.gap_ms.median():.2f} ms (median; {both.gap_ms.min():.2f}-{both.gap_ms.max():.2f} "
            f"over the configurations), the model's {model_ms:.2f} ms: {where}.")


def _pipe_table(table: pd.DataFrame) -> str:
    """A Markdown pipe table of `table`'s cells as they print."""
    rows = [list(map(str, table.columns)), ["---"] * len(table.columns)]
    rows += [[str(v) for v in row] for row in table.itertuples(index=False)]
    return "\n".join("| " + " | ".join(r) + " |" for r in rows)
