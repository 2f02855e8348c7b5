"""One-point groups whose programs differ only in numbers, built once as traced lanes.

Why: a grid of group keys alone (``scene.width`` x ``scene.height``, ``schedule.gpus``) makes
every point a group of one lane, and building each point's program and recurrence model was
nearly all of such a sweep (about 0.5 ms a point, on one core). Here the points of a worker's
task are loaded (each validated as its own load validates it), and those whose experiments
differ from a probe point's only in numbers (:func:`mgpusim.sweeps.traced.differences`) are
built once, with each such number a :class:`~mgpusim.sweeps.traced.Traced` of every point's
value: the program, its effects, the recurrence model, the memory check and the summary
fields no lane computes. Where a branch differs between the points (a host copy split into
another number of parts) the points are built apart, each side traced again; where a number
is used as one concrete value (a GPU count that sets how many tasks there are) the points are
built apart by its values. Points left over (too few to share a build, ones that fail to load
or whose build fails) are built one by one as before.

Checks: the probe (the first point) is built by itself as every group is (:func:`lanes.build`:
the template of its structure simulated, its lane checked against it), and so is the last; both
must have the traced build's structure, lane inputs and summary fields, else the points are
built one by one. ``MGPUSIM_SWEEP_NO_TRACE=1`` builds every one-point group by itself (to
compare).
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import MgpusimError
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim import analytic_lanes as lanes_mod
from mgpusim.sim.analytic import Analytic
from mgpusim.sim.effects import choose_effects
from mgpusim.sweeps import traced as T
from mgpusim.sweeps.loader import ExperimentLoader

#: Fewest points a traced build is tried for (fewer are built one by one).
MIN_POINTS = 8
#: Most traced builds one task tries (each Split or Untraceable costs one more).
MAX_TRACES = 48


def enabled() -> bool:
    return not os.environ.get("MGPUSIM_SWEEP_NO_TRACE")


class _NoLanes(Exception):
    """The traced build says these points cannot run as lanes together (vsync, a refusal)."""


def experiment_differences(probe: Experiment, exp: Experiment) -> dict[tuple, Any] | None:
    """The numbers where `exp` differs from `probe` in its scene and schedule, or None where
    it differs otherwise (its profile object, name, file, profile overrides, a shape or a
    value that is not a number). The raw table is not compared: no build reads it (only
    simulate(), which runs on each point's own experiment)."""
    if exp is probe:
        return {}
    if (exp.profile is not probe.profile or exp.name != probe.name or exp.file != probe.file
            or dict(exp.profile_overrides) != dict(probe.profile_overrides)):
        return None
    out: dict[tuple, Any] = {}
    if T.differences(probe.scene, exp.scene, ("scene",), out) is None:
        return None
    if T.differences(probe.schedule, exp.schedule, ("schedule",), out) is None:
        return None
    return out


def lane_inputs(model: Analytic) -> list[Any]:
    """Every number a lane of `model` takes from it, in one order (:func:`lanes.repeated_lanes`)."""
    out: list[Any] = []
    for phase in model.phases:
        for node in phase:
            if node.stream == "host":
                out.extend(t for _, t in node.part_times)
            else:
                out.append(node.time)
            out.append(node.gap)
    out.extend((model.dispatch, model.submit, model.copy_wake))
    return out


def lanes_of(model: Analytic, n: int) -> lanes_mod.Lanes:
    """The `n` lanes of a traced model: each node's time, parts and gap per point."""
    def arr(x: Any) -> np.ndarray:
        values = T.values_of(x, n)
        if any(type(v) is not int for v in values):
            raise _NoLanes(f"a time that is not an integer: {sorted({type(v).__name__ for v in values})}")
        return np.array(values, dtype=np.int64)
    time_ = [[[arr(t) for _, t in node.part_times] if node.stream == "host" else arr(node.time)
              for node in phase] for phase in model.phases]
    gap = [[arr(node.gap) for node in phase] for phase in model.phases]
    return lanes_mod.Lanes(n, time_, gap, arr(model.dispatch), arr(model.submit), arr(model.copy_wake))


def trace(texp: Experiment, fidelity: str, n: int, static_fields: Callable[..., dict[str, Any]]
          ) -> tuple[Analytic, tuple, dict[str, Any], lanes_mod.Lanes]:
    """The traced build (what :func:`lanes.build` does for one point): the model, its structure,
    the summary fields no lane computes (`static_fields`: :func:`lanes._static_fields`), and
    the lanes. Raises Split, Untraceable, _NoLanes or the build's own error."""
    from mgpusim.schedules.memory_check import check_memory, memory_report  # noqa: PLC0415

    with T.conversions():
        program = build_program(texp)
        if program.refresh_hz:
            raise _NoLanes("vsync")
        needed = choose_effects(program, texp.profile)
        chosen = choose_effects(program, texp.profile, fidelity, needed=needed)
        model = Analytic(program, CostModel(texp.profile), chosen, needed)
        if lanes_mod.lanes_refusal(model) is not None:
            raise _NoLanes("refused")
        signature = lanes_mod.structure(model)
        hash(signature)  # (a traced number in it is Untraceable)
        memory = None
        if "memory_capacity" in chosen:
            check_memory(program, texp)
            memory = memory_report(program, texp)
        static = static_fields(program, chosen, model, fidelity, memory, needed)
        hash(tuple(static))
    lanes = lanes_of(model, n)
    return model, signature, static, lanes


def _agrees(group: Any, signature: tuple, static: Mapping[str, Any], lanes: lanes_mod.Lanes, k: int) -> bool:
    """Whether point k's own build (`group`, built by lanes.build) has the traced build's
    structure, lane inputs and summary fields."""
    model = group.model
    if group.signature != signature:
        return False
    mine = lane_inputs(model)
    traced: list[Any] = []
    for ph, phase in enumerate(model.phases):
        for i, node in enumerate(phase):
            t = lanes.time[ph][i]
            traced.extend(int(a[k]) for a in t) if node.stream == "host" else traced.append(int(t[k]))
            traced.append(int(lanes.gap[ph][i][k]))
    traced.extend((int(lanes.dispatch[k]), int(lanes.submit[k]), int(lanes.copy_wake[k])))
    if mine != traced:
        return False
    summary = group.summary
    for key, value in static.items():
        want = T.values_of(value, len(lanes.dispatch))[k]
        if key not in summary or type(summary[key]) is not type(want) or not T._same([summary[key], want]):
            return False
    return True


class TracedSet:
    """A set of one-point groups built as one traced model: `groups` (in grid order), the probe
    built by itself (`first`), and its static fields and lanes."""

    def __init__(self, groups: list[Any], first: Any, static: dict[str, Any], lanes: lanes_mod.Lanes,
                 seconds: float):
        self.groups, self.first, self.static, self.lanes, self.seconds = groups, first, static, lanes, seconds


def traced_sets(todo: Sequence[Any], path: Path, base: Mapping[str, Any], fidelity: str,
                loader: ExperimentLoader, templates: dict[tuple, dict[str, Any]],
                build: Callable[..., str | None], static_fields: Callable[..., dict[str, Any]]
                ) -> tuple[list[TracedSet], list[Any]]:
    """The one-point groups of `todo` built as traced sets where they can be, and the groups
    left to build one by one (in `todo`'s order). `build`: :func:`lanes.build`, which builds
    one group by itself; `static_fields`: :func:`lanes._static_fields`."""

    exps: list[Experiment | None] = []
    for g in todo:
        try:
            exps.append(loader.load({**base, **g.points[0].keys}))
        except MgpusimError:
            exps.append(None)  # its own build reports why
    left = [i for i, e in enumerate(exps) if e is None]
    #: per point, its probe (the first point of its shape) and its numbers that differ from it
    probe_of: dict[int, Experiment] = {}
    diff_of: dict[int, dict[tuple, Any]] = {}
    work: list[list[int]] = []
    rest = [i for i, e in enumerate(exps) if e is not None]
    while rest and len(work) < MAX_TRACES:  # the points by shape, each diffed once
        probe, other = exps[rest[0]], []
        assert probe is not None
        work.append([])
        for i in rest:
            d = experiment_differences(probe, exps[i])  # type: ignore[arg-type]
            if d is None:
                other.append(i)
            else:
                probe_of[i], diff_of[i] = probe, d
                work[-1].append(i)
        rest = other
    left.extend(rest)
    out: list[TracedSet] = []
    traces = 0
    while work:
        mine = work.pop(0)
        if len(mine) < MIN_POINTS or traces >= MAX_TRACES:
            left.extend(mine)
            continue
        t0 = time.perf_counter()
        traces += 1
        probe = probe_of[mine[0]]  # (the one of every point of `mine`: parts of one shape)
        diffs = [diff_of[i] for i in mine]
        inputs = T.traced_inputs(diffs, probe)
        texp = T.substituted(probe, inputs)
        try:
            model, signature, static, lanes = trace(texp, fidelity, len(mine), static_fields)
        except T.Split as split:
            work.append([i for i, a in zip(mine, split.answers) if a])
            work.append([i for i, a in zip(mine, split.answers) if not a])
            continue
        except T.Untraceable as why:  # the points of each value it needed apart
            by: dict[str, list[int]] = {}
            if why.values is not None and len(why.values) == len(mine):
                keys = [f"{type(v).__name__}:{v!r}" for v in why.values]
            else:
                keys = [repr([d.get(p) for p in sorted(why.paths, key=repr)]) for d in diffs]
            for i, key in zip(mine, keys):
                by.setdefault(key, []).append(i)
            if len(by) == 1:
                left.extend(mine)
            else:
                work.extend(by.values())
            continue
        except (_NoLanes, MgpusimError, ArithmeticError, TypeError, ValueError):
            left.extend(mine)
            continue
        first, last = todo[mine[0]], todo[mine[-1]]
        if build(first, path, base, fidelity, loader, templates) is not None \
                or build(last, path, base, fidelity, loader, templates) is not None \
                or not _agrees(first, signature, static, lanes, 0) \
                or not _agrees(last, signature, static, lanes, len(mine) - 1):
            first.model = last.model = None
            left.extend(mine)
            continue
        out.append(TracedSet([todo[i] for i in mine], first, static, lanes, time.perf_counter() - t0))
    left.sort()
    return out, [todo[i] for i in left]
