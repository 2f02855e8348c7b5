"""Case studies: a source system's own machine, workload and schedule, and what the model predicts.

A case is a folder `experiments/cases/<name>/` holding its profiles, its experiments and a
`case.toml` that lists the runs (an experiment plus `--set` overrides each, optionally one run
per value of a key), the per-run quantities to report (`[[columns]]`) and the quantities that
compare runs (`[[derived]]`). Nothing here writes a file or prints: the output folder, the
table files and the pictures are `mgpusim/commands/case.py`'s.

Column kinds (one value per run):
- `utilization`: mean busy fraction of the resources whose `device.engine` matches `select`
  (a glob, e.g. `gpu*.graphics`), over the steady window;
- `span`: mean wall-clock span (ms) from the first start to the last end of the tasks whose
  step or task name matches `select` (comma-separated globs), over the steady frames that ran
  them;
- `copy_limited_fps`: 1000 / the largest per-frame busy time (ms) of one queue or thread
  among the tasks `select` picks (as for `span`): the frame rate if only those copies limited
  it;
- `rate`: a task's steady rate in Hz (`summary.task_rates_hz[select]`);
- `sections_fit`: how many of the scene's sections (`[[scene.sections]]`) the run's strategy can
  render: a section counts when every GPU that holds it fits it (`mgpusim.schedules.memory_check`: each GPU
  loads its sections in order, whole). It reads the memory model only, so it also applies to a
  run marked `simulate = false` (a data set that overflows cannot be simulated).

Derived kinds (one value per entry): `ratio` (metric of `runs[0]` over `runs[1]`, e.g. the
frame-rate gain) and `difference` (metric of `runs[0]` minus `runs[1]`, e.g. latency a chunked
copy hides); the metric is `fps`, `frame_time_ms` or `latency_ms`, or a column's name.
"""
from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from mgpusim.io.shipped import shipped_dir
from mgpusim.model.config import Table, did_you_mean, read_toml
from mgpusim.model.errors import InputError
from mgpusim.results.summary import Result
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_overrides
from mgpusim.schedules.memory_check import footprints, held_sections, sections_that_fit
from mgpusim.schedules.program import build_program
from mgpusim.sim.simulation import simulate

COLUMN_KINDS = ("utilization", "span", "copy_limited_fps", "rate", "sections_fit")
DERIVED_KINDS = ("ratio", "difference")
SUMMARY_METRICS = ("fps", "frame_time_ms", "latency_ms")


@dataclass(frozen=True)
class Run:
    """One configuration of a case: an experiment and its overrides."""

    name: str
    label: str
    experiment: Path
    sets: tuple[str, ...] = ()
    simulate: bool = True  # False: memory columns only (the data set may not fit)

    def load(self, extra: dict[str, Any] | None = None) -> Experiment:
        return load_experiment(self.experiment, {**parse_overrides(list(self.sets)), **(extra or {})})


@dataclass(frozen=True)
class Column:
    """A per-run quantity (see the module docstring for the kinds)."""

    name: str
    label: str
    kind: str
    select: str = ""
    runs: tuple[str, ...] = ()  # empty: every run (that is simulated, unless memory-only)

    @property
    def memory_only(self) -> bool:
        """Computed from the memory model alone (no simulation needed)."""
        return self.kind == "sections_fit"

    def applies(self, run: Run) -> bool:
        if self.runs:
            return run.name in self.runs
        return run.simulate or self.memory_only


@dataclass(frozen=True)
class Derived:
    """A quantity that compares two runs."""

    name: str
    label: str
    kind: str
    metric: str
    runs: tuple[str, str]


@dataclass(frozen=True)
class Case:
    """One source system's runs, and what to report about them."""

    name: str
    file: Path
    title: str
    description: str
    runs: tuple[Run, ...]
    columns: tuple[Column, ...] = ()
    derived: tuple[Derived, ...] = ()
    timelines: tuple[str, ...] = ()
    timeline_frames: int = 3  # the last this many frames of each timeline run are drawn
    source: str = ""  # the public source the case restates, in words

    def run(self, name: str) -> Run:
        return next(r for r in self.runs if r.name == name)


@dataclass
class CaseResult:
    """Every run's result, its column values, and the derived quantities."""

    case: Case
    results: dict[str, Result]
    experiments: dict[str, Experiment]
    columns: dict[str, dict[str, float]] = field(default_factory=dict)  # run -> column -> value
    derived: dict[str, float] = field(default_factory=dict)


def cases_dir() -> Path:
    return shipped_dir("experiments") / "cases"


def case_names() -> list[str]:
    """The shipped cases: every `experiments/cases/<name>/case.toml`."""
    root = cases_dir()
    return sorted(p.parent.name for p in root.glob("*/case.toml")) if root.is_dir() else []


def case_file(ref: str | Path) -> Path:
    """A case by shipped name, or a `case.toml` path (or its folder)."""
    path = Path(ref)
    if path.is_dir() and (path / "case.toml").is_file():
        return path / "case.toml"
    if path.is_file():
        return path
    candidate = cases_dir() / str(ref) / "case.toml"
    if candidate.is_file():
        return candidate
    names = case_names()
    raise InputError(f"no case of that name{did_you_mean(str(ref), names)}; the cases are: "
                     f"{', '.join(names) or 'none'} (`mgpusim case --list`)", field=str(ref))


def load_case(ref: str | Path) -> Case:
    """Read and check a case file; every error names the file and the field."""
    path = case_file(ref)
    top = Table(read_toml(path), str(path))
    runs = tuple(r for t in top.tables("runs") for r in _runs(t, path.parent))
    names = [r.name for r in runs]
    _unique(names, top, "runs")
    columns = tuple(_column(t, {r.name: r for r in runs}) for t in _list(top, "columns"))
    _unique([c.name for c in columns], top, "columns")
    metrics = set(SUMMARY_METRICS) | {c.name for c in columns}
    simulated = {r.name for r in runs if r.simulate}
    derived = tuple(_derived(t, simulated, metrics) for t in _list(top, "derived"))
    _unique([d.name for d in derived], top, "derived")
    timelines = tuple(top.get("timelines", list, []))
    for t in timelines:
        if t not in simulated:
            raise top.error("timelines", f"{t!r} is not a simulated run of this case")
    case = Case(name=top.get("name", str, path.parent.name), file=path, title=top.get("title", str),
                description=top.get("description", str, ""), runs=runs, columns=columns,
                derived=derived, timelines=timelines,
                timeline_frames=top.get("timeline_frames", int, 3, minimum=1, maximum=50),
                source=top.get("source", str, ""))
    top.finish()
    return case


def _list(top: Table, key: str) -> list[Table]:
    return top.tables(key) if top.has(key) else []


def _unique(names: list[str], top: Table, key: str) -> None:
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise top.error(key, f"names must be unique, repeated: {', '.join(dup)}")


def _runs(t: Table, base: Path) -> list[Run]:
    """One run, or one per value of `each` (a one-key table: key -> list of values)."""
    name, label = t.get("name", str), t.get("label", str)
    exp = base / t.get("experiment", str)
    if not exp.is_file():
        raise t.error("experiment", f"{str(exp)!r} does not exist")
    sets = tuple(t.get("set", list, [])) + _sections_set(t.table("sections", {}))
    simulated = t.get("simulate", bool, True)
    each = t.table("each", {})
    keys = list(each.data)
    if len(keys) > 1:
        raise t.error("each", "give one key whose values make one run each")
    values = each.get(keys[0], list) if keys else []
    if keys and (not values or any(isinstance(v, (list, dict)) for v in values)):
        raise each.error(keys[0], "expected a non-empty list of single values")
    each.finish()
    t.finish()
    if not keys:
        return [Run(name, label, exp, sets, simulated)]
    key = keys[0]
    return [Run(f"{name}_{v}", f"{label}, {key.rsplit('.', 1)[-1]} {v}", exp, sets + (f"{key}={v}",), simulated)
            for v in values]


def _sections_set(t: Table) -> tuple[str, ...]:
    """`sections = { count, name, geometry_bytes, texture_bytes }`: that many equal sections as
    a `scene.sections` override (empty table: none)."""
    if not t.data:
        return ()
    count = t.get("count", int, minimum=1, maximum=1024)
    name = t.get("name", str, "section")
    geometry, texture = t.get("geometry_bytes", int, minimum=0), t.get("texture_bytes", int, 0, minimum=0)
    t.finish()
    items = ", ".join(f"{{name = {json.dumps(f'{name}_{i:02d}')}, geometry_bytes = {geometry}, "
                      f"texture_bytes = {texture}}}" for i in range(count))
    return (f"scene.sections=[{items}]",)


def _column(t: Table, runs: dict[str, Run]) -> Column:
    col = Column(name=t.get("name", str), label=t.get("label", str),
                 kind=t.get("kind", str, choices=COLUMN_KINDS), select=t.get("select", str, ""),
                 runs=tuple(t.get("runs", list, [])))
    t.finish()
    for r in col.runs:
        if r not in runs:
            raise t.error("runs", f"{r!r} is not a run of this case")
        if not runs[r].simulate and not col.memory_only:
            raise t.error("runs", f"{r!r} is not simulated (simulate = false): a {col.kind} column needs a result")
    if not col.memory_only and not col.select:
        raise t.error("select", f"a {col.kind} column needs select")
    return col


def _derived(t: Table, runs: set[str], metrics: set[str]) -> Derived:
    pair = t.get("runs", list)
    d = Derived(name=t.get("name", str), label=t.get("label", str),
                kind=t.get("kind", str, choices=DERIVED_KINDS),
                metric=t.get("metric", str, choices=sorted(metrics)), runs=tuple(pair))  # type: ignore[arg-type]
    t.finish()
    if len(pair) != 2 or any(r not in runs for r in pair):
        raise t.error("runs", f"expected two simulated runs of this case, got {pair!r}")
    return d


def run_case(case: Case, frames: int | None = None,
             progress: Callable[[str], None] | None = None) -> CaseResult:
    """Simulate every run (with `frames` frames each when given, a fifth of them warm-up)
    and compute the columns and the derived quantities. `progress(run)`: called before each
    simulated run."""
    extra = {} if frames is None else {"schedule.frames": frames, "schedule.warmup_frames": max(1, frames // 5)}
    exps = {r.name: _load(case, r, extra) for r in case.runs}
    results = {}
    for r in case.runs:
        if r.simulate:
            if progress is not None:
                progress(r.name)
            results[r.name] = simulate(exps[r.name])
    out = CaseResult(case, results, exps)
    for run in case.runs:
        out.columns[run.name] = {c.name: column_value(c, results.get(run.name), exps[run.name])
                                 for c in case.columns if c.applies(run)}
    for d in case.derived:
        a, b = (metric(out, r, d.metric) for r in d.runs)
        out.derived[d.name] = a / b if d.kind == "ratio" else a - b
    return out


def _load(case: Case, run: Run, extra: dict[str, Any]) -> Experiment:
    """A run's experiment; an error in it also names the case file and the run."""
    try:
        return run.load(extra)
    except InputError as exc:
        raise InputError(f"{exc} (run {run.name!r} of {case.file})") from None


def metric(cr: CaseResult, run: str, name: str) -> float:
    """A summary metric or a column value of one run (NaN where the column does not apply)."""
    if name in SUMMARY_METRICS:
        return float(cr.results[run].summary[name])
    return float(cr.columns[run].get(name, math.nan))


def steady(trace: pd.DataFrame, exp: Experiment) -> pd.DataFrame:
    """The trace rows of the frames after warm-up."""
    return trace[trace["frame"] >= exp.schedule.warmup_frames]


def column_value(col: Column, result: Result | None, exp: Experiment) -> float:
    """One column's value for one run (`result` None: a memory-only column of a run that is
    not simulated)."""
    if col.kind == "sections_fit":
        return float(sections_rendered(exp))
    assert result is not None, "load_case lets only memory columns apply to runs not simulated"
    if col.kind == "utilization":
        busy = [v for k, v in result.summary.get("utilization", {}).items() if fnmatch.fnmatchcase(k, col.select)]
        return float(sum(busy) / len(busy)) if busy else math.nan
    if col.kind == "rate":
        return float(result.summary.get("task_rates_hz", {}).get(col.select, math.nan))
    rows = steady(result.trace, exp)
    if col.kind == "span":
        return span_ms(rows, col.select)
    return copy_limited_fps(rows, col.select)


def sections_rendered(exp: Experiment) -> int:
    """How many of the scene's sections the strategy can render on its GPUs: a section counts
    when every GPU that holds it fits it (each GPU loads its sections in order, whole)."""
    if not exp.scene.sections:
        raise InputError("a sections_fit column needs [[scene.sections]] in the experiment", file=exp.file,
                         field="scene.sections")
    fit: dict[str, bool] = {}
    for fp in footprints(build_program(exp), exp.scene):
        fitting = set(sections_that_fit(fp, exp.scene, exp.profile.gpus[fp.gpu].memory_bytes))
        for name in held_sections(fp, exp.scene):
            fit[name] = fit.get(name, True) and name in fitting
    return sum(fit.values())


def _matching(rows: pd.DataFrame, select: str) -> pd.DataFrame:
    """The rows whose step or task name matches one of the comma-separated globs."""
    globs = [g.strip() for g in select.split(",") if g.strip()]

    def hit(name: str) -> bool:
        return any(fnmatch.fnmatchcase(name, g) for g in globs)
    mask = rows["step"].astype(str).map(hit) | rows["task"].astype(str).map(hit)
    return rows[mask]


def span_ms(rows: pd.DataFrame, select: str) -> float:
    """Mean per-frame span (ms) of the selected tasks, over the frames that ran them."""
    sel = _matching(rows, select)
    if not len(sel):
        return 0.0
    g = sel.groupby("frame")
    return float((g["end_ns"].max() - g["start_ns"].min()).mean() / 1e6)


def copy_limited_fps(rows: pd.DataFrame, select: str) -> float:
    """1000 / the busiest queue's or thread's mean per-frame time (ms) on the selected tasks."""
    sel = _matching(rows, select)
    frames = rows["frame"].nunique()
    if not len(sel) or not frames:
        return math.inf
    busy = (sel["end_ns"] - sel["start_ns"]).groupby([sel["device"], sel["engine"]]).sum()
    return float(1e9 / (busy.max() / frames)) if busy.max() > 0 else math.inf


def table(cr: CaseResult) -> pd.DataFrame:
    """A row per run: its label, GPUs, frame time, fps, latency and its column values."""
    rows = []
    for run in cr.case.runs:
        exp = cr.experiments[run.name]
        s = cr.results[run.name].summary if run.name in cr.results else {}
        row = {"run": run.name, "configuration": run.label, "GPUs": exp.schedule.gpus,
               "frame time (ms)": s.get("frame_time_ms", math.nan), "fps": s.get("fps", math.nan),
               "latency (ms)": s.get("latency_ms", math.nan)}
        for c in cr.case.columns:
            row[c.label] = cr.columns[run.name].get(c.name, math.nan)
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(value: Any, kind: str = "") -> str:
    """A table cell: busy fractions in percent, section counts whole, others to 3 figures."""
    if not isinstance(value, float):
        return str(value)
    if math.isnan(value):
        return ""
    if math.isinf(value):
        return "unbounded"
    if kind == "utilization":
        return f"{value:.0%}"
    if kind == "sections_fit":
        return f"{value:.0f}"
    return f"{value:.3g}" if abs(value) < 1 else f"{value:,.2f}" if abs(value) < 1000 else f"{value:,.0f}"


def markdown(cr: CaseResult) -> str:
    """The predicted table and the derived quantities, as markdown."""
    df = table(cr).drop(columns=["run"])
    df = df.loc[:, [c for c in df.columns if not df[c].isna().all()]]
    kinds = {c.label: c.kind for c in cr.case.columns}
    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(_fmt(v, kinds.get(col, "")) for col, v in zip(df.columns, row)) + " |"
              for row in df.itertuples(index=False)]
    if cr.case.derived:
        lines += ["", "| derived quantity | predicted |", "|---|---|"]
        for d in cr.case.derived:
            v = cr.derived[d.name]
            shown = f"{v:.2f}x" if d.kind == "ratio" and d.metric in ("fps",) else _fmt(v)
            lines.append(f"| {d.label} | {shown} |")
    return "\n".join(lines) + "\n"


#: The predicted table in a docs page sits between these lines (docs/cases/refresh.py fills it).
BLOCK_START, BLOCK_END = "<!-- predictions:start -->", "<!-- predictions:end -->"


def docs_block(page: str) -> str:
    """The text between the prediction markers of a docs page ('' when it has none)."""
    if BLOCK_START not in page or BLOCK_END not in page:
        return ""
    return page.split(BLOCK_START, 1)[1].split(BLOCK_END, 1)[0].strip("\n") + "\n"


def with_docs_block(page: str, block: str) -> str:
    """The page with its prediction block replaced by `block`."""
    head, rest = page.split(BLOCK_START, 1)
    tail = rest.split(BLOCK_END, 1)[1]
    return f"{head}{BLOCK_START}\n{block.rstrip()}\n{BLOCK_END}{tail}"
