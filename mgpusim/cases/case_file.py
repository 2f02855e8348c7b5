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

Published figures (`[[published]]`) are the source's own results beside the quantity that
predicts each (a derived quantity's name, or `run:metric`); a figure either tests the model or
sets one `[[parameters]]` entry (`sets`), never more than one: the calibration rule, stated in
the case file before any comparison. A parameter is a value applied as overrides to the runs it
names; :func:`calibrate` finds, figure by figure, the value that makes its prediction equal the
figure (the committed value is what the case file holds).
"""
from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable, Mapping, cast

import pandas as pd

from mgpusim.io.shipped import shipped_dir
from mgpusim.model.errors import InputError
from mgpusim.model.toml_checks import Table, did_you_mean, name_problem, read_toml
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
    #: `sections = {count, name, geometry_bytes, texture_bytes}`: equal scene sections
    sections: Mapping[str, Any] | None = None

    def load(self, extra: dict[str, Any] | None = None) -> Experiment:
        """The experiment with the run's overrides and `extra` (a `sections.<field>` key of
        `extra` replaces that field of the run's sections)."""
        extra = dict(extra or {})
        section = {**(self.sections or {}), **{k.removeprefix("sections."): extra.pop(k)
                                               for k in list(extra) if k.startswith("sections.")}}
        sets = list(self.sets) + ([_sections_override(section)] if section else [])
        return load_experiment(self.experiment, {**parse_overrides(sets), **extra})


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
class Parameter:
    """A value the source did not state, applied as overrides (`keys`: key -> factor, each key
    set to value x factor, rounded when `integer`) to the runs whose names match `runs`."""

    name: str
    label: str
    value: float
    keys: Mapping[str, float]
    source: str
    runs: tuple[str, ...] = ("*",)
    #: the interval :func:`calibrate` searches (None: not searched, the value is a rule's)
    bounds: tuple[float, float] | None = None
    integer: bool = False

    def applies(self, run: str) -> bool:
        return any(fnmatch.fnmatchcase(run, g) for g in self.runs)

    def overrides(self, value: float) -> dict[str, Any]:
        return {k: (int(round(value * f)) if self.integer else value * f) for k, f in self.keys.items()}


@dataclass(frozen=True)
class Published:
    """A source's own figure and the quantity that predicts it; `sets`: the parameter this
    figure calibrates ("" = a test of the model)."""

    name: str
    label: str
    value: float
    quantity: str
    source: str
    sets: str = ""


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
    parameters: tuple[Parameter, ...] = ()
    published: tuple[Published, ...] = ()

    def run(self, name: str) -> Run:
        return next(r for r in self.runs if r.name == name)

    def parameter(self, name: str) -> Parameter:
        return next(p for p in self.parameters if p.name == name)


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
    parameters = tuple(_parameter(t, names) for t in _list(top, "parameters"))
    _unique([p.name for p in parameters], top, "parameters")
    quantities = {d.name for d in derived}
    memory = {c.name for c in columns if c.memory_only}
    published = tuple(_published(t, quantities, simulated, set(names), metrics, memory,
                                 {p.name for p in parameters}) for t in _list(top, "published"))
    _unique([p.name for p in published], top, "published")
    setters = [p.sets for p in published if p.sets]
    _unique(setters, top, "published")  # a parameter is set by one figure at most
    case = Case(name=top.name("name", path.parent.name), file=path, title=top.get("title", str),
                description=top.get("description", str, ""), runs=runs, columns=columns,
                derived=derived, timelines=timelines,
                timeline_frames=top.get("timeline_frames", int, 3, minimum=1, maximum=50),
                source=top.get("source", str, ""), parameters=parameters, published=published)
    top.finish()
    return case


def _parameter(t: Table, runs: list[str]) -> Parameter:
    keys_t = t.table("keys")
    keys = {k: keys_t.get(k, float) for k in keys_t.data}
    keys_t.finish()
    if not keys:
        raise t.error("keys", "a parameter sets at least one override key")
    bounds = t.get("bounds", list, [])
    if bounds and (len(bounds) != 2 or not all(isinstance(b, (int, float)) for b in bounds)
                   or not bounds[0] < bounds[1]):
        raise t.error("bounds", f"expected [low, high] with low < high, got {bounds!r}")
    p = Parameter(name=t.get("name", str), label=t.get("label", str), value=t.get("value", float),
                  keys=MappingProxyType(keys), source=t.get("source", str),
                  runs=tuple(t.get("runs", list, ["*"])),
                  bounds=(float(bounds[0]), float(bounds[1])) if bounds else None,
                  integer=t.get("integer", bool, False))
    t.finish()
    if not any(p.applies(r) for r in runs):
        raise t.error("runs", f"{list(p.runs)!r} matches no run of this case")
    return p


def _published(t: Table, derived: set[str], simulated: set[str], runs: set[str], metrics: set[str],
               memory: set[str], parameters: set[str]) -> Published:
    p = Published(name=t.get("name", str), label=t.get("label", str), value=t.get("value", float),
                  quantity=t.get("quantity", str), source=t.get("source", str),
                  sets=t.get("sets", str, ""))
    t.finish()
    run, _, name = p.quantity.partition(":")
    per_run = name in metrics and (run in simulated or (run in runs and name in memory))
    if not (p.quantity in derived or per_run):
        raise t.error("quantity", f"{p.quantity!r} is neither a derived quantity of this case nor "
                      "run:metric with a simulated run and a metric or column")
    if p.sets and p.sets not in parameters:
        raise t.error("sets", f"{p.sets!r} is not a [[parameters]] entry of this case")
    return p


def _list(top: Table, key: str) -> list[Table]:
    return top.tables(key) if top.has(key) else []


def _unique(names: list[str], top: Table, key: str) -> None:
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise top.error(key, f"names must be unique, repeated: {', '.join(dup)}")


def _runs(t: Table, base: Path) -> list[Run]:
    """One run, or one per value of `each` (a one-key table: key -> list of values)."""
    name, label = t.name("name"), t.get("label", str)
    exp = base / t.get("experiment", str)
    if not exp.is_file():
        raise t.error("experiment", f"{str(exp)!r} does not exist")
    sets = t.get("set", list, [])
    for i, item in enumerate(sets):
        if not isinstance(item, str):
            raise t.error(f"set[{i}]", f"expected a KEY=VALUE string, got {item!r}")
    sets = tuple(sets)
    sections = _sections(t.table("sections", {}))
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
        return [Run(name, label, exp, sets, simulated, sections)]
    key = keys[0]
    for v in values:  # each run's name names its timeline picture
        problem = name_problem(f"{name}_{v}")
        if problem:
            raise each.error(key, f"the run name {f'{name}_{v}'!r} {problem}")
    return [Run(f"{name}_{v}", f"{label}, {key.rsplit('.', 1)[-1]} {v}", exp, sets + (f"{key}={v}",),
                simulated, sections) for v in values]


def _sections(t: Table) -> Mapping[str, Any] | None:
    """`sections = { count, name, geometry_bytes, texture_bytes }`, checked (empty: none)."""
    if not t.data:
        return None
    out = {"count": t.get("count", int, minimum=1, maximum=1024), "name": t.get("name", str, "section"),
           "geometry_bytes": t.get("geometry_bytes", int, minimum=0),
           "texture_bytes": t.get("texture_bytes", int, 0, minimum=0)}
    t.finish()
    return MappingProxyType(out)


def _sections_override(s: Mapping[str, Any]) -> str:
    """That many equal sections as a `scene.sections` override."""
    geometry, texture = int(round(s["geometry_bytes"])), int(round(s.get("texture_bytes", 0)))
    prefix = s.get("name", "section")
    items = ", ".join(f"{{name = {json.dumps(f'{prefix}_{i:02d}')}, geometry_bytes = {geometry}, "
                      f"texture_bytes = {texture}}}" for i in range(int(s["count"])))
    return f"scene.sections=[{items}]"


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
                metric=t.get("metric", str, choices=sorted(metrics)), runs=tuple(pair))
    t.finish()
    if len(pair) != 2 or any(r not in runs for r in pair):
        raise t.error("runs", f"expected two simulated runs of this case, got {pair!r}")
    return d


def run_case(case: Case, frames: int | None = None, values: Mapping[str, float] | None = None,
             only: set[str] | None = None, progress: Callable[[str], None] | None = None) -> CaseResult:
    """Simulate every run (with `frames` frames each when given, a fifth of them warm-up)
    and compute the columns and the derived quantities. `values`: parameter values instead of
    the case file's; `only`: simulate just these runs (quantities of other runs are left out);
    `progress(run)`: called before each simulated run."""
    extra = {} if frames is None else {"schedule.frames": frames, "schedule.warmup_frames": max(1, frames // 5)}
    runs = [r for r in case.runs if only is None or r.name in only]
    exps = {r.name: _load(case, r, {**extra, **parameter_overrides(case, r.name, values)}) for r in runs}
    results = {}
    for r in runs:
        if r.simulate:
            if progress is not None:
                progress(r.name)
            # a parameter is set on every run it names; a variant with no use for it is no what-if
            try:
                results[r.name] = simulate(exps[r.name], check_unused=False)
            except InputError as exc:  # (a run too long to simulate frame by frame: `frames`' doing)
                if frames is None or exc.field != "schedule.frames":
                    raise
                raise InputError(f"run {r.name!r} of {case.file}: {exc.detail}", field="--frames") from None
    out = CaseResult(case, results, exps)
    for run in runs:
        out.columns[run.name] = {c.name: column_value(c, results.get(run.name), exps[run.name])
                                 for c in case.columns if c.applies(run)}
    for d in case.derived:
        if all(r in results for r in d.runs):
            a, b = (metric(out, r, d.metric) for r in d.runs)
            out.derived[d.name] = a / b if d.kind == "ratio" else a - b
    return out


def parameter_overrides(case: Case, run: str, values: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The overrides the case's parameters put on one run (`values` replacing their values)."""
    out: dict[str, Any] = {}
    for p in case.parameters:
        if p.applies(run):
            out.update(p.overrides((values or {}).get(p.name, p.value)))
    return out


def _load(case: Case, run: Run, extra: dict[str, Any]) -> Experiment:
    """A run's experiment; an error in it also names the case file and the run."""
    try:
        return run.load(extra)
    except InputError as exc:
        raise InputError(f"{exc} (run {run.name!r} of {case.file})") from None


def predicted(cr: CaseResult, quantity: str) -> float:
    """A published figure's prediction: a derived quantity, or `run:metric`."""
    if quantity in cr.derived:
        return cr.derived[quantity]
    run, _, name = quantity.partition(":")
    return metric(cr, run, name)


def quantity_runs(case: Case, quantity: str) -> set[str]:
    """The runs a quantity needs simulated."""
    for d in case.derived:
        if d.name == quantity:
            return set(d.runs)
    return {quantity.partition(":")[0]}


def comparison(cr: CaseResult) -> pd.DataFrame:
    """Each published figure beside its prediction: quantity, published, predicted, error
    (predicted / published - 1)."""
    rows = []
    for p in cr.case.published:
        value = predicted(cr, p.quantity)
        rows.append({"quantity": p.name, "published": p.value, "predicted": value,
                     "error": value / p.value - 1 if p.value else math.nan})
    return pd.DataFrame(rows, columns=["quantity", "published", "predicted", "error"])


def comparison_markdown(cr: CaseResult) -> str:
    """The comparison as markdown: figure, source, published, predicted, error, and what the
    figure sets (its parameter's value) or 'test'."""
    df = comparison(cr)
    lines = ["| published figure | published | predicted | error | role |", "|---|---|---|---|---|"]
    for p, row in zip(cr.case.published, df.itertuples(index=False)):
        if p.sets:
            par = cr.case.parameter(p.sets)
            role = f"sets {par.label} = {_fmt(float(par.value))}"
        else:
            role = "test (predicted)"
        lines.append(f"| {p.label} | {_fmt(float(p.value))} | {_fmt(float(cast(float, row.predicted)))} | "
                     f"{row.error:+.1%} | {role} |")
    return "\n".join(lines) + "\n"


def calibrate(case: Case, frames: int | None = None, rounds: int = 3, tol: float = 1e-4,
              steps: int = 40) -> dict[str, float]:
    """The parameter values the published figures set: for each figure with `sets`, the value
    within the parameter's bounds at which the prediction equals the figure (bisection; the
    prediction must move one way with the parameter), the other parameters held; `rounds`
    passes, since a parameter may move another figure's prediction."""
    values = {p.name: p.value for p in case.parameters}
    setters = [p for p in case.published if p.sets]
    for _ in range(rounds):
        for fig in setters:
            par = case.parameter(fig.sets)
            if par.bounds is None:
                continue
            only = set().union(*(quantity_runs(case, f.quantity) for f in setters
                                 if f.sets == par.name))
            miss = _figure_miss(case, frames, values, par, only, fig)
            lo, hi = par.bounds
            f_lo, f_hi = miss(lo), miss(hi)
            if f_lo * f_hi > 0:  # out of reach: the end nearer the figure
                values[par.name] = lo if abs(f_lo) < abs(f_hi) else hi
                continue
            for _ in range(steps):
                mid = (lo + hi) / 2
                f_mid = miss(mid)
                if abs(f_mid) <= tol * abs(fig.value) or hi - lo <= tol * max(abs(lo), abs(hi), 1e-12):
                    break
                lo, hi, f_lo = (mid, hi, f_mid) if f_mid * f_lo > 0 else (lo, mid, f_lo)
            values[par.name] = round((lo + hi) / 2) if par.integer else (lo + hi) / 2
    return values


def _figure_miss(case: Case, frames: int | None, values: Mapping[str, float], par: Parameter,
                 only: set[str], fig: Published) -> Callable[[float], float]:
    """How far the prediction of `fig` is from the figure with `par` at a value and the other
    parameters at `values` (read when called), simulating only the runs in `only`."""
    def miss(v: float) -> float:
        cr = run_case(case, frames, {**values, par.name: v}, only)
        return predicted(cr, fig.quantity) - fig.value
    return miss


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


def amdahl_gain(gain_2: float, gpus: int) -> float:
    """The gain at `gpus` GPUs on the Amdahl line through a 1 -> 2 GPU gain: 1 / ((1 - p) + p / N)
    with p = 2 (1 - 1 / gain_2) (p < 0 where two GPUs are slower than one)."""
    p = 2.0 * (1.0 - 1.0 / gain_2)
    return 1.0 / ((1.0 - p) + p / gpus)


def extrapolation(cr: CaseResult) -> pd.DataFrame:
    """Beyond the fitted point: for every family of frame-rate gains over one 1-GPU run (the
    derived fps ratios that share their denominator), each gain at 3 or more GPUs as the model
    predicts it beside the Amdahl line through the same family's 1 -> 2 GPU gain. A model whose
    overhead does not grow with each added GPU predicts more than the line."""
    gains: dict[tuple, dict[int, tuple[str, float]]] = {}
    for d in cr.case.derived:
        if d.kind != "ratio" or d.metric != "fps" or d.name not in cr.derived:
            continue
        top, base = (cr.experiments[r].schedule.gpus for r in d.runs)
        if base == 1:
            gains.setdefault(_family(cr, d.runs), {})[top] = (d.label, cr.derived[d.name])
    rows = []
    for family in gains.values():
        if 2 not in family:
            continue
        two = family[2][1]
        for gpus, (label, value) in sorted(family.items()):
            if gpus >= 3:
                rows.append({"quantity": label, "gpus": gpus, "gain_2": two, "predicted": value,
                             "amdahl": amdahl_gain(two, gpus)})
    return pd.DataFrame(rows, columns=["quantity", "gpus", "gain_2", "predicted", "amdahl"])


def _family(cr: CaseResult, runs: tuple[str, ...] | list[str]) -> tuple:
    """Which family a gain over a 1-GPU run belongs to: that run, and the schedule of the run
    it divides (its name and options but the GPU count), so weak and strong scaling over one
    1-GPU run are two families."""
    schedule = cr.experiments[runs[0]].schedule
    options = tuple(sorted((k, repr(v)) for k, v in schedule.options.items() if k != "gpus"))
    return (runs[1], schedule.name, options)


def extrapolation_markdown(cr: CaseResult) -> str:
    """:func:`extrapolation` as a table ('' when the case has no such family)."""
    df = extrapolation(cr)
    if df.empty:
        return ""
    lines = ["| quantity | 1 -> 2 GPUs | predicted | Amdahl through 1 -> 2 |", "|---|---|---|---|"]
    lines += [f"| {r.quantity} | {r.gain_2:.2f}x | {r.predicted:.2f}x | {r.amdahl:.2f}x |"
              for r in df.itertuples()]
    return "\n".join(lines) + "\n"


#: The predicted table in a docs page sits between these lines (docs/cases/refresh.py fills it).
BLOCK_START, BLOCK_END = "<!-- predictions:start -->", "<!-- predictions:end -->"
#: The comparison with the published figures sits between these.
COMPARISON = ("<!-- comparison:start -->", "<!-- comparison:end -->")


def docs_block(page: str, markers: tuple[str, str] = (BLOCK_START, BLOCK_END)) -> str:
    """The text between a docs page's markers ('' when it has none)."""
    start, end = markers
    if start not in page or end not in page:
        return ""
    return page.split(start, 1)[1].split(end, 1)[0].strip("\n") + "\n"


def with_docs_block(page: str, block: str, markers: tuple[str, str] = (BLOCK_START, BLOCK_END)) -> str:
    """The page with the block between its markers replaced by `block`."""
    start, end = markers
    head, rest = page.split(start, 1)
    tail = rest.split(end, 1)[1]
    return f"{head}{start}\n{block.rstrip()}\n{end}{tail}"
