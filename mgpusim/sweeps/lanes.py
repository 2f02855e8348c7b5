"""A sweep's points at the analytic level as numpy lanes (:mod:`mgpusim.sim.analytic_lanes`).

Why: at ``--fidelity analytic`` one point costs a few milliseconds, nearly all of it loading
the experiment and building its program, so a 100k-point grid over hardware what-ifs would
take minutes point by point while the recurrence itself is the same for most points.

How the grid is split:

- *Lane keys* change only pass costs: ``profile.gpus.<i|*>.speed`` and
  ``profile.gpus.<i|*>.costs.<kind>.fixed_ns`` / ``.ns_per_<term>`` of a cost the profile
  already has. Each value is loaded once (checked like any override) and the coefficients it
  sets read from the loaded profile; a key whose profile differs from the base anywhere else,
  two keys that set the same coefficient, or a grid over the experiment's ``profile`` file
  makes them ordinary keys, and so does another ``profile.`` grid key (a group key) one of
  whose values changes a coefficient a lane key sets or which pass costs the profile has.
- Every other key (scene, schedule, other profile keys) is a *group* key: each combination
  of their values is a group, built once with the real code (its first point loaded in memory,
  :mod:`mgpusim.sweeps.loader`, its program and the recurrence's model built), with the fields
  no lane computes (frames, effects, memory, fidelity, modelled effects) worked out as
  simulate() works them out. The first group of each structure also runs its first point
  through :func:`mgpusim.sim.simulation.simulate`: that summary is the template whose order
  of fields the others follow, and its lane must reproduce it (else the group runs point by
  point); every other group's first lane must reproduce its own model's pass times, the only
  times the lanes work out themselves.
- Groups whose programs have one structure (:func:`~mgpusim.sim.analytic_lanes.structure`)
  run as one set of lanes: the pass times of each lane from its coefficients (the cost
  model's formula and rounding), every other time from its group. A grid of group keys alone
  runs so too, one lane per group.

``MGPUSIM_SWEEP_NO_LANES=1`` in the environment runs every point one by one (to compare).
Groups are built and run in local worker processes where the sweep has several.

Points fall back to the per-point path, transparently and with the same columns, where the
group cannot run as lanes (skippable tasks, vsync, long runs, a point that fails to load or
run), or a lane's pass would exceed the time bound (the point then reports that error).
"""
from __future__ import annotations

import math
import os
import time
from collections import abc
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from mgpusim.io import table_files
from mgpusim.model import limits as L
from mgpusim.model.costs import CostModel, term_coefficient
from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.profile_reads import outside_shipped, shipped_profiles
from mgpusim.model.tasks import PassTask
from mgpusim.results.settled import FIELDS as SETTLING_FIELDS
from mgpusim.results.settled import settling_arrays
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim import analytic_lanes as lanes_mod
from mgpusim.sim.analytic import Analytic
from mgpusim.sim.effects import approximations as left_out
from mgpusim.sim.effects import choose_effects
from mgpusim.sweeps import shared_build
from mgpusim.sweeps.loader import _SHARED, ExperimentLoader, shared
from mgpusim.sweeps.store import save_batch
from mgpusim.sweeps.traced import Traced

#: A coefficient a lane key sets: (GPU index, "speed") or (GPU index, kind, "fixed_ns" | term).
Coef = tuple
#: The summary fields a lane computes (the rest come from its group's first point).
LANE_FIELDS = ("frame_time_ms", "fps", "latency_ms", "frame_time_jitter_ms", "frame_time_min_ms",
               "frame_time_max_ms", "window_ns.0", "window_ns.1")
_TOLERANCE = 1e-9


@dataclass
class Plan:
    """The grid split: lane keys with each value's coefficients, group keys."""

    lane_keys: list[str]
    group_keys: list[str]
    #: lane key -> per value, the coefficients it sets
    coefs: dict[str, list[dict[Coef, float]]] = field(default_factory=dict)
    #: why there are no lane keys, or why a key is not one (for the benchmark and docs)
    notes: list[str] = field(default_factory=list)


def plan(path: Path, grid: Mapping[str, Sequence[Any]], base: Mapping[str, Any],
         loader: ExperimentLoader | None = None) -> Plan:
    """Which grid keys run as lanes (see the module doc). `loader`: loads the experiment
    (default: one of its own)."""
    profile_keys = [k for k in grid if k.startswith("profile.")]
    lane, notes, coefs = [], [], {}
    if "profile" in grid or "profile" in base:
        return Plan([], list(grid), notes=["the profile file itself changes"])
    load = (loader or ExperimentLoader(path)).load
    try:
        start = load(dict(base)).profile
    except MgpusimError:
        return Plan([], list(grid), notes=["the base experiment does not load"])
    for key in profile_keys:
        found = _lane_coefs(load, base, key, grid[key], start)
        if isinstance(found, str):
            notes.append(f"{key}: {found}")
        else:
            lane.append(key)
            coefs[key] = found
    others = [k for k in profile_keys if k not in lane]
    if others and lane:  # another profile key could change what a lane key sets
        clash = _group_profile_clash(load, base, {k: grid[k] for k in others}, start,
                                     set().union(*(_touched(coefs[k]) for k in lane)))
        if clash is not None:
            notes.append(f"{clash}: every profile key is then a group key")
            return Plan([], list(grid), notes=notes)
    for i, a in enumerate(lane):
        for b in lane[:i]:
            if _touched(coefs[a]) & _touched(coefs[b]):
                notes.append(f"{a} and {b} set the same coefficient")
                return Plan([], list(grid), notes=notes)
    return Plan(lane, [k for k in grid if k not in lane], coefs, notes)


def _group_profile_clash(load: Callable[[dict[str, Any]], Experiment], base: Mapping[str, Any],
                         others: Mapping[str, Sequence[Any]], start: HardwareProfile,
                         touched: set[Coef]) -> str | None:
    """Why profile keys that are not lane keys (group keys) keep the lane keys from being
    lanes, or None: a value of one that changes a coefficient a lane key sets, or which
    coefficients the profile has (its GPUs, their kinds and terms), would make the lanes'
    tables wrong in its groups. (Each group's first lane is still checked against its own
    model: the lanes' coefficients over the group's profile.)"""
    base_coefs = _all_coefs(start)
    for key, values in others.items():
        for value in values:
            try:
                prof = load({**base, key: value}).profile
            except MgpusimError:
                continue  # its points fail on their own
            found = _all_coefs(prof)
            if set(found) != set(base_coefs):
                return f"{key}={value!r} changes which pass costs the profile has"
            if any(found[c] != base_coefs[c] for c in touched):
                return f"{key}={value!r} changes a coefficient a lane key sets"
    return None


def _lane_coefs(load: Callable[[dict[str, Any]], Experiment], base: Mapping[str, Any], key: str,
                values: Sequence[Any], start: HardwareProfile) -> list[dict[Coef, float]] | str:
    """Per value, the coefficients `key` sets, or why it is not a lane key. Which GPUs a key
    reaches is read from the loaded profiles, not from its path (``gpus.0`` names the first
    ``[[gpus]]`` table, which may stand for several GPUs): the coefficients that differ
    between the key's values, each of which must then equal the value itself."""
    parts = key.split(".")[1:]
    if not (len(parts) == 3 and parts[0] == "gpus" and parts[2] == "speed"
            or len(parts) == 5 and parts[0] == "gpus" and parts[2] == "costs"
            and (parts[4] == "fixed_ns" or parts[4].startswith("ns_per_"))):
        return "not a pass-cost coefficient"
    loaded = []
    for value in values:
        try:
            prof = load({**base, key: value}).profile
        except MgpusimError:
            return "a value does not load (its points report why)"
        if _strip(prof) != _strip(start):
            return "changes more than pass costs"
        loaded.append(_all_coefs(prof))
    touched = {c for c in loaded[0] if len({coefs[c] for coefs in loaded}) > 1}
    if not touched:
        return "its values set no coefficient to different numbers"
    try:
        if any(coefs[c] != float(v) for coefs, v in zip(loaded, values) for c in touched):
            return "a coefficient it changes is not its value"
    except (TypeError, ValueError):
        return "not a number"
    return [{c: coefs[c] for c in sorted(touched)} for coefs in loaded]


def _strip(profile: HardwareProfile) -> HardwareProfile:
    """The profile with every pass-cost coefficient and speed zeroed (kinds and terms kept)."""
    gpus = tuple(replace(g, speed=0.0, costs=MappingProxyType(
        {k: replace(c, fixed_ns=0.0, ns_per=MappingProxyType(dict.fromkeys(c.ns_per, 0.0)))
         for k, c in g.costs.items()})) for g in profile.gpus)
    return replace(profile, gpus=gpus)


def _all_coefs(profile: HardwareProfile) -> dict[Coef, float]:
    """Every pass-cost coefficient and speed of the profile's GPUs."""
    out: dict[Coef, float] = {}
    for i, g in enumerate(profile.gpus):
        out[(i, "speed")] = g.speed
        for kind, cost in g.costs.items():
            out[(i, kind, "fixed_ns")] = cost.fixed_ns
            out.update({(i, kind, term): v for term, v in cost.ns_per.items()})
    return out


def _touched(per_value: list[dict[Coef, float]]) -> set[Coef]:
    return set().union(*per_value) if per_value else set()


_LEAVES = frozenset((str, int, float, bool, type(None)))


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts and lists as dotted columns: {"a": {"b": 1}, "w": [2, 3]} ->
    {"a.b": 1, "w.0": 2, "w.1": 3}."""
    kind = type(value)
    if kind in _LEAVES:  # (the commonest case, and an abc check costs more than the rest)
        return {prefix: value}
    if kind is dict or isinstance(value, abc.Mapping):
        items: Iterable[tuple[Any, Any]] = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return {prefix: value}
    out: dict[str, Any] = {}
    for k, v in items:
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


# ----- groups ---------------------------------------------------------------------------------
@dataclass
class Group:
    """The points of one combination of group-key values: the model of its first point, the
    first point's summary, and the points' indices into the lane combinations."""

    points: list[Any]
    combos: np.ndarray  # per point (row), the index of each lane key's value
    model: Analytic | None = None
    summary: dict[str, Any] | None = None
    signature: tuple | None = None
    #: the group this is a slice of (None: a whole group), and whether it has its first point
    origin: "Group | None" = None
    has_first: bool = True
    #: its first point's lane did not reproduce that point: every slice runs point by point
    failed: bool = False
    #: `summary` is the first point's simulate() summary, which its lane is checked against
    #: (else the fields no lane computes, worked out for it, in its structure's template: its
    #: lane is checked at its pass times, the only times the lanes work out themselves)
    checked: bool = True


def groups(plan_: Plan, todo: Sequence[Any], grid: Mapping[str, Sequence[Any]]) -> list[Group]:
    """The points to run, grouped by their group-key values, in grid order. (A point's value
    of each key is a digit of its index in the grid: the product, last key fastest.)"""
    keys = list(grid)
    sizes = np.array([len(grid[k]) for k in keys], dtype=np.int64)
    strides = np.concatenate([np.cumprod(sizes[::-1])[::-1][1:], [1]])
    index = np.fromiter((p.index for p in todo), dtype=np.int64, count=len(todo))
    digits = {k: (index // strides[j]) % sizes[j] for j, k in enumerate(keys)}
    gid = np.zeros(len(todo), dtype=np.int64)
    for k in plan_.group_keys:
        gid = gid * len(grid[k]) + digits[k]
    combos = np.stack([digits[k] for k in plan_.lane_keys], axis=1) if plan_.lane_keys \
        else np.zeros((len(todo), 0), dtype=np.int64)
    order = np.argsort(gid, kind="stable")
    bounds = np.flatnonzero(np.diff(gid[order])) + 1
    members = np.split(order, bounds) if len(order) else []
    members.sort(key=lambda m: m[0])
    return [Group([todo[i] for i in m.tolist()], combos[m]) for m in members]


def build(group: Group, path: Path, base: Mapping[str, Any], fidelity: str,
          loader: ExperimentLoader | None = None, templates: dict[tuple, dict[str, Any]] | None = None
          ) -> str | None:
    """Load the group's first point (from `loader`: parsed once, overridden in memory) and
    build the model its lanes share. Returns why the group must run point by point (None: it
    can run as lanes).

    The fields of the summary that no lane computes (frames, effects, memory, fidelity,
    modelled effects) are worked out for the group here, as simulate() works them out. The
    first group of each structure (and of each set of those fields) runs its first point
    through :func:`mgpusim.sim.simulation.simulate` as well: its summary is the template
    (`templates`) whose order of fields the others follow and whose lane is checked against
    it; a summary field the template has that is neither a lane's nor one worked out here
    makes every group run simulate() so (nothing is copied from another point)."""
    from mgpusim.schedules.memory_check import check_memory, memory_report  # noqa: PLC0415
    from mgpusim.sim.simulation import simulate  # noqa: PLC0415

    first = group.points[0]
    try:
        exp = (loader or ExperimentLoader(path)).load({**base, **first.keys})
        program = build_program(exp)
        if program.refresh_hz:
            return "vsync"
        needed = choose_effects(program, exp.profile)  # (once: the effects' tests read the program)
        chosen = choose_effects(program, exp.profile, fidelity, needed=needed)
        model = Analytic(program, CostModel(exp.profile), chosen, needed)
        refusal = lanes_mod.lanes_refusal(model)
        if refusal is not None:
            return refusal
        signature = lanes_mod.structure(model)
        if "memory_capacity" in chosen:
            check_memory(program, exp)  # an overflow is the point's error (simulate's check)
        static = _static_fields(program, chosen, model, fidelity,
                                memory_report(program, exp) if "memory_capacity" in chosen else None, needed)
        key = (signature, tuple(sorted(static)))
        template = templates.get(key) if templates is not None else None
        summary = _from_template(template, static) if template is not None else None
        if summary is None:
            summary = flatten(simulate(exp, fidelity=fidelity).summary)
            if templates is not None and _from_template(summary, static) is not None:
                templates[key] = summary
        else:
            group.checked = False
        group.summary = summary
    except MgpusimError as exc:
        return str(exc)
    group.model, group.signature = model, signature
    return None


#: Summary fields every lane computes itself (beside LANE_FIELDS), by prefix or name.
LANE_PREFIXES = ("utilization.", "fast_forward.", "task_rates_hz.", "settling.")
LANE_NAMES = frozenset((*LANE_FIELDS, "settled"))


def _static_fields(program: Any, chosen: frozenset[str], model: Analytic, fidelity: str,
                   memory: Mapping[str, Any] | None, needed: frozenset[str] | None = None) -> dict[str, Any]:
    """The flattened summary fields of a point that no lane computes, as simulate() gives them
    at the analytic level for a program without skippable tasks (no tied skip decisions)."""
    out: dict[str, Any] = {"frames": program.frames, "warmup_frames": program.warmup_frames}
    approximations = list(model.approximations)
    out["effects"] = {"analytic_exact": not approximations,
                      **({"analytic_approximations": approximations} if approximations else {})}
    if memory is not None:
        out["memory"] = memory
    out.update(fidelity=fidelity, modelled_effects=sorted(chosen))
    out["approximations"] = left_out(program, model.costs.profile, chosen, needed)  # (never full here)
    return flatten(out)


def _from_template(template: Mapping[str, Any], static: Mapping[str, Any]) -> dict[str, Any] | None:
    """The template's fields in its order, those in `static` with static's values (the lane
    fields are the lanes' own); None if the template has a field that is neither."""
    if not set(static) <= set(template):
        return None
    out = {}
    for key, value in template.items():
        if key in static:
            out[key] = static[key]
        elif key in LANE_NAMES or key.startswith(LANE_PREFIXES):
            out[key] = value
        else:
            return None
    return out


def _model(group: Group) -> Analytic:
    """The model `build` made for the group (only groups it built run as lanes)."""
    assert group.model is not None
    return group.model


def _summary(group: Group) -> dict[str, Any]:
    """The summary of the group's first point, as `build` simulated it."""
    assert group.summary is not None
    return group.summary


def group_lanes(group: Group, plan_: Plan) -> tuple[lanes_mod.Lanes, np.ndarray]:
    """The group's lanes (pass times from each point's coefficients) and, per lane, whether
    its pass times are within the time bound (a lane out of it runs point by point)."""
    model, n = _model(group), len(group.points)
    lanes = lanes_mod.base_lanes(model, n)
    ok = np.ones(n, dtype=bool)
    if not plan_.lane_keys:
        return lanes, ok
    combos = group.combos
    coef: dict[Coef, np.ndarray] = {}
    for j, key in enumerate(plan_.lane_keys):
        for c in _touched(plan_.coefs[key]):
            table = np.array([v.get(c, np.nan) for v in plan_.coefs[key]], dtype=np.float64)
            coef[c] = table[combos[:, j]]
    profile = model.costs.profile
    for ph, phase in enumerate(model.phases):
        for i, node in enumerate(phase):
            if isinstance(node.task, PassTask):
                ns, good = _pass_ns(profile, node.task, coef, n)
                if ns is not None:
                    lanes.time[ph][i] = ns
                    ok &= good
                    if group.has_first and not (good[0] and ns[0] == node.time):
                        (group.origin or group).failed = True  # lane 0 is the model's own point
    return lanes, ok


def _pass_ns(profile: HardwareProfile, task: PassTask, coef: Mapping[Coef, np.ndarray], n: int
             ) -> tuple[np.ndarray | None, np.ndarray]:
    """A pass's time per lane, as :meth:`CostModel.pass_ns` computes it (the same float
    operations in the same order, one rounding half up), or None where no lane changes it."""
    d, kind, work = task.queue.device, task.kind, task.work
    gpu = profile.gpus[d]
    keys = [(d, "speed"), (d, kind, "fixed_ns"), *((d, kind, t) for t in work)]
    if not any(k in coef for k in keys):
        return None, np.ones(n, dtype=bool)

    def get(k: Coef, default: float) -> Any:
        return coef[k] if k in coef else default
    speed = get((d, "speed"), gpu.speed)
    cost = gpu.costs.get(kind)
    if cost is None:  # a reference kind (checked when the group's first point ran)
        total = np.full(n, work.get("reference_ns", 0.0)) / speed
    else:
        total = np.full(n, get((d, kind, "fixed_ns"), cost.fixed_ns), dtype=np.float64)
        for term, amount in work.items():
            if amount == 0:
                continue
            c = term_coefficient(cost, kind, term, profile.source, f"gpus[{d}].costs.{kind}")
            if c is None:  # a term the profile may lack: it costs nothing
                continue
            total = total + get((d, kind, term), c) * amount
        total = total / speed
    good = total <= L.MAX_TASK_NS  # also false for NaN
    return np.floor(np.where(good, total, 0.0) + 0.5).astype(np.int64), good


# ----- running ------------------------------------------------------------------------------
@dataclass
class Batch:
    """Lanes of groups of one structure, run together."""

    groups: list[Group]
    model: Analytic


def run_batch(batch: Batch, plan_: Plan) -> tuple[pd.DataFrame, list[Any]]:
    """The batch's records as one table (column `id`, then `error`, `wall_s` and the summary
    columns) and the points that must run point by point instead."""
    t0 = time.perf_counter()
    if plan_.lane_keys:
        built = [group_lanes(g, plan_) for g in batch.groups]
        lanes = lanes_mod.concat([b[0] for b in built])
        oks = [b[1] for b in built]
    else:  # every lane is its group's model as it is
        lanes = repeated_lanes([_model(g) for g in batch.groups], [len(g.points) for g in batch.groups])
        oks = [np.ones(len(g.points), dtype=bool) for g in batch.groups]
    result = _run_lanes(batch.model, lanes)
    parts: list[dict[str, Any]] = []
    fallback, at = [], 0
    for g, ok in zip(batch.groups, oks):
        n = len(g.points)
        mine = {k: v[at:at + n] for k, v in result.items()}
        at += n
        root = g.origin or g
        if g.has_first and g.checked and not _first_matches(_summary(g), mine):
            root.failed = True
        if root.failed:
            fallback.extend(g.points)
            continue
        fallback.extend(p for p, good in zip(g.points, ok) if not good)
        if ok.any():
            parts.append(_records(g, mine, ok))
    df = _joined(parts) if parts else pd.DataFrame({"id": []})
    if len(df):
        df["wall_s"] = round((time.perf_counter() - t0) / len(df), 9)
    return df, fallback


def repeated_lanes(models: Sequence[Analytic], sizes: Sequence[int]) -> lanes_mod.Lanes:
    """``concat([base_lanes(m, n) for m, n in zip(models, sizes)])`` for models of one
    structure, an array per node rather than one per node and model (a batch of one-lane
    groups, as a grid of scene keys alone makes, would otherwise build thousands of arrays
    of one value)."""
    counts = np.asarray(sizes, dtype=np.int64)

    def per_lane(values: list[int]) -> np.ndarray:
        return np.repeat(np.array(values, dtype=np.int64), counts)
    phases = [m.phases for m in models]
    time_: list[list[Any]] = []
    gap: list[list[np.ndarray]] = []
    for ph, phase in enumerate(models[0].phases):
        time_.append([[per_lane([p[ph][i].part_times[k][1] for p in phases]) for k in range(len(node.part_times))]
                      if node.stream == "host" else per_lane([p[ph][i].time for p in phases])
                      for i, node in enumerate(phase)])
        gap.append([per_lane([p[ph][i].gap for p in phases]) for i in range(len(phase))])
    return lanes_mod.Lanes(int(counts.sum()), time_, gap, per_lane([m.dispatch for m in models]),
                           per_lane([m.submit for m in models]), per_lane([m.copy_wake for m in models]))


def _run_lanes(model: Analytic, lanes: lanes_mod.Lanes) -> dict[str, np.ndarray]:
    """:func:`mgpusim.sim.analytic_lanes.run_lanes` with each lane's `settled` and `settling.*`
    (:mod:`mgpusim.results.settled`) beside its summary figures, so that a lane's row says what
    the point's own run would. Why its chunk loop is repeated here: `run_lanes` keeps only the
    summary's figures, and the rule needs every frame's start and present."""
    why = lanes_mod.lanes_refusal(model)
    if why is not None:
        raise InputError(f"schedule {model.program.schedule!r} cannot run as lanes: {why}")
    out: dict[str, list[np.ndarray]] = {}
    chunk = lanes_mod._chunk(model)
    for lo in range(0, lanes.n, chunk):
        run = lanes_mod._Pass(model, lanes.take(slice(lo, lo + chunk)), detect=True, log=True)
        run.run()
        summary = lanes_mod._summary(model, run)
        summary.update(lanes_mod._utilization(run, summary))
        settle = settling_arrays(run.start, run.present, model.program.warmup_frames)
        summary["settled"] = settle["frame_time_settled"] & settle["latency_settled"]
        summary.update({f"settling.{key}": settle[key] for key in SETTLING_FIELDS})
        for key, values in summary.items():
            out.setdefault(key, []).append(values)
    return {k: np.concatenate(v) for k, v in out.items()}


def _first_matches(summary: Mapping[str, Any], lane: Mapping[str, np.ndarray]) -> bool:
    """Whether lane 0 (the group's first point) reproduces that point's own summary."""
    if bool(lane["settled"][0]) != summary.get("settled"):
        return False
    for key in (*LANE_FIELDS, *(k for k in lane if k.startswith("utilization."))):
        want, got = summary.get(key), lane[key][0]
        if want is None:
            if not (isinstance(got, float) and math.isnan(got)):
                return False
        elif not math.isclose(float(got), float(want), rel_tol=_TOLERANCE, abs_tol=1e-12):
            return False
    used = bool(lane["fast_forward.used"][0])
    if used != summary.get("fast_forward.used"):
        return False
    return not used or all(int(lane[f"fast_forward.{k}"][0]) == summary[f"fast_forward.{k}"]
                           for k in ("period_frames", "period_ns", "from_frame"))


def _joined(parts: list[dict[str, Any]]) -> pd.DataFrame:
    """The groups' records (:func:`_records`) as one table: what one table per group joined by
    `pd.concat` would be (the columns in order of first appearance; a column some groups lack
    is missing there, NaN; a column of one type keeps it, integers with floats or missing
    values become floats, anything else objects), made at once (a batch of many one-lane
    groups would otherwise build a table per point)."""
    columns = list(dict.fromkeys(c for p in parts for c in p))
    sizes = [len(p["id"]) for p in parts]
    out: dict[str, Any] = {}
    for col in columns:
        pieces = [_as_array(p[col], n) if col in p else None for p, n in zip(parts, sizes)]
        kinds = {a.dtype for a in pieces if a is not None}
        whole = all(a is not None for a in pieces)
        if whole and len(kinds) == 1:
            out[col] = pieces[0] if len(pieces) == 1 else np.concatenate(pieces)  # type: ignore[arg-type]
        elif all(k.kind in "iuf" for k in kinds):
            out[col] = np.concatenate([a.astype(np.float64) if a is not None else np.full(n, np.nan)
                                       for a, n in zip(pieces, sizes)])
        else:
            out[col] = np.concatenate([a.astype(object) if a is not None else np.full(n, np.nan, dtype=object)
                                       for a, n in zip(pieces, sizes)])
    return pd.DataFrame(out)


def _as_array(values: Any, n: int) -> np.ndarray:
    """A record column as the array pd.DataFrame would make of it: an array as it is, a list
    of one value by that value's type (text and None as objects)."""
    if isinstance(values, np.ndarray):
        return values
    if isinstance(values, list) and values and all(v is values[0] for v in values):
        return _constant(values[0], n)
    return pd.Series(values).to_numpy()


def _records(group: Group, lane: Mapping[str, np.ndarray], ok: np.ndarray) -> dict[str, Any]:
    """The group's good lanes as records (columns): the first point's summary with each
    lane's own timing, utilization and fast-forward fields."""
    whole = bool(ok.all())  # (the commonest case: slices, no copies)
    rows: Sequence[int] = range(len(ok)) if whole else np.flatnonzero(ok).tolist()
    keep: slice | np.ndarray = slice(None) if whole else np.asarray(rows, dtype=np.int64)
    n = len(rows)
    cols: dict[str, Any] = {"id": [group.points[i].id for i in rows], "error": _constant(None, n)}
    lane_cols = {k: v[keep] for k, v in lane.items() if not k.startswith("fast_forward.")}
    lane_cols = {k: v for k, v in lane_cols.items()
                 if not (k.startswith("utilization.") and np.isnan(v).all())}
    first = _summary(group)
    summary = {k: v for k, v in first.items()
               if not k.startswith(("utilization.", "fast_forward.", "task_rates_hz.", "warnings."))}
    for key, value in summary.items():
        if key in lane_cols:
            cols[key] = lane_cols.pop(key)
        elif type(value) is Traced:  # one value per point (a traced build's)
            cols[key] = _per_point(value.v)[keep]
        else:
            cols[key] = _constant(value, n)
    cols.update(lane_cols)
    cols.update(_warnings(first, [group.points[i].keys for i in rows]))
    cols.update(_fast_forward(lane, keep))
    program = _model(group).program
    if program.rate_tasks:  # none skipped (lanes have no skippable tasks): every frame counts
        span = cols["window_ns.1"] - cols["window_ns.0"]
        frames = program.frames - (program.warmup_frames + 1)
        rate = np.where(span > 0, frames * 1e9 / np.where(span > 0, span, 1), 0.0)
        cols.update({f"task_rates_hz.{name}": rate for name in program.rate_tasks})
        cols["task_rates_hz.frames"] = cols["fps"]
    return cols


def _warnings(first: Mapping[str, Any], keys: Sequence[Mapping[str, Any]]) -> dict[str, list[Any]]:
    """Each point's `warnings.<i>` columns, as its own simulate() would give them: the first
    point's warnings about the base overrides, then those about this point's grid values (a
    lane's pass costs differ from the first point's), in the grid's order of keys.
    :func:`~mgpusim.model.profile_reads.outside_shipped` judges each override alone, so each
    key's each value is judged once (a value is one object of the grid's list, at every point
    that has it); most grids have no value outside the shipped profiles at all."""
    grid = tuple(keys[0]) if keys else ()
    base = [w for k, w in first.items() if k.startswith("warnings.")
            and not any(str(w).startswith(f"{g} = ") for g in grid)]
    judged: dict[str, dict[int, list[str]]] = {}
    for key in grid:
        values = {id(point[key]): point[key] for point in keys}
        judged[key] = {at: outside_shipped({key: v}, shipped_profiles()) for at, v in values.items()}
    if any(w for by_value in judged.values() for w in by_value.values()):
        per_point = [base + [w for key in grid for w in judged[key][id(point[key])]] for point in keys]
    else:
        per_point = [base] * len(keys)
    width = max((len(w) for w in per_point), default=0)
    return {f"warnings.{j}": [w[j] if j < len(w) else None for w in per_point] for j in range(width)}


def _constant(value: Any, n: int) -> np.ndarray:
    """``_as_array([value] * n, n)``: the column of `n` copies of one value, as a record's
    column of them is made (without a list of `n` items to look through)."""
    return np.full(n, value) if _typed(value) else np.full(n, value, dtype=object)


def _per_point(values: Sequence[Any]) -> np.ndarray:
    """The column of one value per point as :func:`_joined` makes it of one-point groups'
    columns (each :func:`_constant` of its value): of the values' one type where they have
    one, as floats where they are all numbers that are not bools, else objects."""
    kinds = {_kind(v) for v in values}
    if len(kinds) == 1 and None not in kinds:
        return np.array(values, dtype=kinds.pop())
    if kinds <= {np.int64, np.float64}:
        return np.array([float(v) for v in values], dtype=np.float64)
    out = np.empty(len(values), dtype=object)
    out[:] = list(values)
    return out


def _kind(value: Any) -> Any:
    """The dtype :func:`_constant` gives a column of `value` (None: objects)."""
    if not _typed(value):
        return None
    return np.bool_ if isinstance(value, bool) else np.int64 if isinstance(value, int) else np.float64


def _typed(value: Any) -> bool:
    """Whether :func:`_as_array` gives a column of `value` a type of its own (else objects)."""
    return isinstance(value, (bool, int, float)) and not (isinstance(value, int) and not isinstance(value, bool)
                                                          and not -2**63 <= value < 2**63)


def _fast_forward(lane: Mapping[str, np.ndarray], keep: slice | np.ndarray) -> dict[str, Any]:
    """The summary's fast_forward fields per lane, as the analytic level words them."""
    used = lane["fast_forward.used"][keep]
    p, ns, f1 = (lane[f"fast_forward.{k}"][keep] for k in ("period_frames", "period_ns", "from_frame"))
    why = [f"state repeats every {a} frame(s), {b} ns, from frame {c}" if u else "no repeat found"
           for u, a, b, c in zip(used.tolist(), p.tolist(), ns.tolist(), f1.tolist())]
    out: dict[str, Any] = {"fast_forward.used": used, "fast_forward.why": why}
    if used.any():
        for key, values in (("period_frames", p), ("period_ns", ns), ("from_frame", f1)):
            out[f"fast_forward.{key}"] = values if used.all() else np.where(used, values, np.nan)
    return out


def batches(groups_: list[Group], max_lanes: int = 1 << 16) -> Iterator[Batch]:
    """Built groups of one structure together, at most about `max_lanes` lanes a batch (a
    batch is saved whole: a killed sweep loses at most the batch it was running)."""
    by: dict[tuple | None, list[Group]] = {}
    for whole in groups_:
        for lo in range(0, len(whole.points), max_lanes):  # the slice with the first point first
            g = whole if len(whole.points) <= max_lanes else replace(
                whole, points=whole.points[lo:lo + max_lanes], combos=whole.combos[lo:lo + max_lanes],
                origin=whole, has_first=not lo)
            by.setdefault(g.signature, []).append(g)
    for same in by.values():
        run: list[Group] = []
        size = 0
        for g in same:
            if run and size + len(g.points) > max_lanes:
                yield Batch(run, _model(run[0]))
                run, size = [], 0
            run.append(g)
            size += len(g.points)
        if run:
            yield Batch(run, _model(run[0]))


class LaneRun:
    """Runs `todo` as lanes where it can: iterate for one records table per batch; afterwards
    `fallback` holds the points left to run one by one (in grid order). `workers`: local
    processes building and running the groups (1: here), `store`: the sweep's folder, whose
    lock they must not hold."""

    def __init__(self, path: Path, base: Mapping[str, Any], grid: Mapping[str, Sequence[Any]],
                 todo: Sequence[Any], fidelity: str, max_lanes: int = 1 << 16,
                 loader: ExperimentLoader | None = None, workers: int = 1, store: Any = None):
        self.path, self.base, self.grid, self.todo = path, base, grid, list(todo)
        self.fidelity, self.max_lanes = fidelity, max_lanes
        self.loader = loader or ExperimentLoader(path)
        self.workers, self.store = workers, store
        self.fallback: list[Any] = []
        self.plan: Plan | None = None

    def __iter__(self) -> Iterator[pd.DataFrame]:
        """Every grid at the analytic level runs as lanes (groups of one structure together,
        however few lanes each has), unless MGPUSIM_SWEEP_NO_LANES is set."""
        left = self.todo
        if self.fidelity == "analytic" and left and not os.environ.get("MGPUSIM_SWEEP_NO_LANES"):
            self.plan = plan(self.path, self.grid, self.base, self.loader)
            left = []
            yield from self._lanes()
        self.fallback.extend(left)
        self.fallback.sort(key=lambda p: p.index)

    def _lanes(self) -> Iterator[pd.DataFrame]:
        plan_ = self.plan
        assert plan_ is not None  # planned by __iter__
        per_task = TRACED_PER_TASK if not plan_.lane_keys and shared_build.enabled() else GROUPS_PER_TASK
        tasks = split(groups(plan_, self.todo, self.grid), self.workers, self.max_lanes, per_task)
        args = [(str(self.path), self.base, self.fidelity, plan_, t, self.max_lanes) for t in tasks]
        _SHARED.setdefault(str(self.path), self.loader)  # run_groups' here and in forked workers
        if self.workers == 1 or len(tasks) == 1:
            done: Iterator[tuple[list[pd.DataFrame], list[Any]]] = (run_groups(*a) for a in args)
            for frames, fallback in done:
                self.fallback.extend(fallback)
                yield from frames
            return
        from concurrent.futures import as_completed  # noqa: PLC0415

        from mgpusim.sweeps.pool import local_pool  # noqa: PLC0415

        self.loader._table()  # parsed before the workers fork: each inherits it
        points = self.store.points if self.store is not None else None
        with local_pool(min(self.workers, len(tasks)), self.store) as pool:
            for fut in as_completed([pool.submit(run_groups, *a, points) for a in args]):
                frames, fallback = fut.result()
                self.fallback.extend(fallback)
                for frame in frames:  # saved by the worker: read back (cheaper than pickled)
                    yield _saved(table_files.read_parquet(frame), frame) if isinstance(frame, Path) else frame


def _saved(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """A batch a worker saved as `path` (`attrs["saved"]`: the sweep saves it no more)."""
    df.attrs["saved"] = str(path)
    return df


def run_groups(path: str, base: Mapping[str, Any], fidelity: str, plan_: Plan, todo: list[Group],
               max_lanes: int, points: Path | None = None) -> tuple[list[Any], list[Any]]:
    """Build `todo`'s groups and run them as lanes, in whatever process: the batches' records
    and the points left to run one by one. `points`: the sweep's points folder, where a worker
    saves each batch itself (:meth:`~mgpusim.sweeps.store.PointStore.save_batch`), returning
    its file instead of its table."""
    loader = shared(path)
    built: list[Group] = []
    fallback: list[Any] = []
    templates: dict[tuple, dict[str, Any]] = {}
    frames: list[Any] = []
    if not plan_.lane_keys and shared_build.enabled() and len(todo) >= shared_build.MIN_POINTS:
        sets, todo = shared_build.traced_sets(todo, Path(path), base, fidelity, loader, templates,
                                              build, _static_fields)
        done, back = run_traced(sets)
        todo = sorted([*todo, *back], key=lambda g: g.points[0].index)
        frames.extend(df if points is None else save_batch(points, df) for df in done)
    for g in todo:
        if build(g, Path(path), base, fidelity, loader, templates) is None:
            built.append(g)
        else:
            fallback.extend(g.points)
    for batch in batches(built, max_lanes):
        df, left = run_batch(batch, plan_)
        fallback.extend(left)
        if len(df):
            frames.append(df if points is None else save_batch(points, df))
    return frames, fallback


def run_traced(sets: list[shared_build.TracedSet]) -> tuple[list[pd.DataFrame], list[Group]]:
    """Each traced set's records as one table (as :func:`run_batch` makes a batch's), and the
    groups of any set whose first lane does not reproduce its probe's simulate() summary,
    handed back to be built one by one."""
    frames: list[pd.DataFrame] = []
    back: list[Group] = []
    for s in sets:
        t0 = time.perf_counter()
        first, n = s.first, len(s.groups)
        result = _run_lanes(_model(first), s.lanes)
        if first.checked and not _first_matches(_summary(first), {k: v[:1] for k, v in result.items()}):
            for g in s.groups:
                g.model = None
            back.extend(s.groups)
            continue
        summary = {k: s.static[k] if k in s.static else v for k, v in _summary(first).items()}
        whole = Group([g.points[0] for g in s.groups], np.zeros((n, 0), dtype=np.int64), first.model,
                      summary, first.signature)
        df = _joined([_records(whole, result, np.ones(n, dtype=bool))])
        df["wall_s"] = round((time.perf_counter() - t0 + s.seconds) / len(df), 9)
        frames.append(df)
    return frames, back


#: Most groups one task of a pool builds (it also runs them: a task's batches are its own).
GROUPS_PER_TASK = 256
#: The same for one-point groups built together (:mod:`.shared_build`): a task builds each
#: structure of its points once, so fewer larger tasks (about two per worker).
TRACED_PER_TASK = 4096


def split(todo: list[Group], workers: int, max_lanes: int, per_task: int = GROUPS_PER_TASK) -> list[list[Group]]:
    """The groups in consecutive runs, one per task: about four per worker (two where
    `per_task` is TRACED_PER_TASK), each at most `max_lanes` lanes and `per_task` groups (one
    run for a single worker)."""
    if workers <= 1:
        return [todo] if todo else []
    lanes_total = sum(len(g.points) for g in todo)
    per_lanes = min(max_lanes, max(4096, -(-lanes_total // (4 * workers))))
    runs = 2 if per_task == TRACED_PER_TASK else 4
    per_groups = min(per_task, max(1, -(-len(todo) // (runs * workers))))
    out: list[list[Group]] = []
    run: list[Group] = []
    size = 0
    for g in todo:
        if run and (size + len(g.points) > per_lanes or len(run) >= per_groups):
            out.append(run)
            run, size = [], 0
        run.append(g)
        size += len(g.points)
    if run:
        out.append(run)
    return out
