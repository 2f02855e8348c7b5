"""A study as data: which configurations are measured, which ones calibrate, which are held out.

A study file (TOML) names a profile, the microbenchmarks (sweeps to measure, or a folder of
committed tables), how measured runs are taken, a calibration recipe and two lists of
configurations (an experiment file plus `--set` overrides each). Every path in it is relative
to the file. The lavapipe main job and the NVIDIA validations are studies; adding a machine is
adding a study file.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Sequence

from mgpusim.model.config import Table, read_toml
from mgpusim.model.errors import InputError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.work_terms import WORK_TERMS
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_overrides


@dataclass(frozen=True)
class Entry:
    """One configuration: an experiment file with `--set` style overrides."""

    name: str
    experiment: Path
    sets: tuple[str, ...] = ()

    def load(self, profile: HardwareProfile | Path | str | None = None,
             extra: Sequence[str] = ()) -> Experiment:
        """The entry's experiment, simulated on `profile` (default: the experiment's own)."""
        prof = str(profile) if isinstance(profile, Path) else profile
        return load_experiment(self.experiment, parse_overrides([*self.sets, *extra]), profile=prof)


@dataclass(frozen=True)
class Microbenchmarks:
    """Pass sweeps to measure (`rounds` x `reps` repetitions each), or committed `tables`.
    `pairs`: sweeps measured alone and on two simulated GPUs at once, for the kinds whose
    `cores` is fitted from how much two of them slow each other (lavapipe)."""

    sweeps: tuple[tuple[str, Mapping[str, tuple[Any, ...]]], ...] = ()
    pairs: tuple[tuple[str, Mapping[str, tuple[Any, ...]]], ...] = ()
    rounds: int = 1
    reps: int = 5
    warmup: int = 2
    folder: Path | None = None
    files: tuple[str, ...] = ()

    def tables(self, measured: Path) -> list[Path]:
        """The tables the calibration reads: committed ones, or those measured under `measured`."""
        if self.folder is not None:
            return [self.folder / f for f in self.files]
        return [measured / f"{name}.csv" for name in self.passes()]

    def passes(self) -> list[str]:
        """Every pass measured, once each, in the order of the sweeps then the pairs."""
        return list(dict.fromkeys(name for name, _ in (*self.sweeps, *self.pairs)))


@dataclass(frozen=True)
class RunSettings:
    """How each configuration is measured: repeats (interleaved), timed length, untimed frames
    before each run, and whether the steady window of the repeats is what gets compared."""

    repeats: int = 1
    run_seconds: float = 0.0
    prewarm_frames: int | None = None
    max_frames: int = 2000
    steady_window: bool = False


@dataclass(frozen=True)
class Recipe:
    """What the calibration fits, in order: the microbenchmark tables (on a lavapipe skeleton
    made from their machine record when `base` is 'machine', else on the study profile's own
    structure); host copy cost from `host_copy_table` on the host's memcpy threads; costs and
    host keys copied from another profile; pass costs from the calibration runs (`run_fitted`
    kinds, all kinds when empty; runs of `run_fit_gpus` GPUs only when set; `run_fit_terms` work
    terms only when set); the `run_fit_alone` kinds (those only multi-GPU runs have) scaled to
    their instances that ran alone on the cores; the copies' fixed cost from the runs' copies
    alone on the cores (`copy_setup`); the queues' idle gap (`task_gap`); the host-copy
    thread's wake latency (`host_copy_wake`); the copies left behind a young core-filling pass
    of another GPU (`busy_wake`); a grid search of host effects."""

    base: str = "profile"
    host_copy_table: str | None = None
    copy_from: Path | None = None
    copy_costs: tuple[str, ...] = ()
    copy_host: tuple[str, ...] = ()
    run_fitted: tuple[str, ...] = ()
    run_fit_gpus: int | None = None
    run_fit_terms: tuple[str, ...] | None = None
    run_fit_alone: tuple[str, ...] = ()
    task_gap: bool = False
    host_copy_wake: bool = False
    busy_wake: bool = False
    copy_setup: bool = False
    host_grid: Mapping[str, tuple[Any, ...]] = field(default_factory=lambda: MappingProxyType({}))
    #: what the grid search scores: the prediction's frame-time error, or the replay's (the
    #: timeline on the runs' own durations, so that cost errors cannot set host effects)
    host_grid_level: str = "prediction"


@dataclass(frozen=True)
class Study:
    name: str
    file: Path
    description: str
    profile: Path
    microbenchmarks: Microbenchmarks
    runs: RunSettings
    recipe: Recipe
    calibration: tuple[Entry, ...]
    held_out: tuple[Entry, ...]
    #: committed measured runs of each half (None: measured into the study's output folder)
    calibration_runs: Path | None = None
    held_out_runs: Path | None = None
    #: lavapipe rasterizer threads per host core for every measurement (None: lavapipe's own
    #: default, one per core)
    lavapipe_threads_per_core: float | None = None

    def lavapipe_threads(self) -> int | None:
        """LP_NUM_THREADS of every lavapipe GPU the study measures, from this machine's cores.

        Why more threads than cores: with one rasterizer thread per core a lavapipe mesh pass
        runs in one of two modes at random, for tens of frames at a time, 1.3x apart (both
        threads busy, or one doing nearly all the bins while the other waits); with twice as
        many threads the bins spread evenly and every run lands in the fast mode."""
        if self.lavapipe_threads_per_core is None:
            return None
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        return max(1, round(self.lavapipe_threads_per_core * (cores or 1)))

    def entries(self, held_out: bool = True) -> tuple[Entry, ...]:
        return self.calibration + (self.held_out if held_out else ())


def load_study(path: Path | str) -> Study:
    """Read and check a study file; every error names the file and the field."""
    path = Path(path)
    top = Table(read_toml(path), str(path))
    base = path.parent
    cal, held = top.table("calibration", {}), top.table("held_out", {})
    study = Study(
        name=top.get("name", str, path.stem),
        file=path,
        description=top.get("description", str, ""),
        profile=_existing(base / top.get("profile", str), top, "profile"),
        microbenchmarks=_microbenchmarks(top.table("microbenchmarks", {}), base),
        runs=_runs(top.table("runs", {})),
        recipe=_recipe(cal, base),
        calibration=_entries(cal, base),
        held_out=_entries(held, base),
        calibration_runs=_folder(cal, base),
        held_out_runs=_folder(held, base),
        lavapipe_threads_per_core=top.get("lavapipe_threads_per_core", float, None, minimum=0.25,
                                          maximum=16),
    )
    cal.finish()
    held.finish()
    top.finish()
    names = [e.name for e in study.entries()]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"configuration names must be unique, repeated: {', '.join(dup)}", file=str(path))
    return study


def _existing(p: Path, t: Table, key: str) -> Path:
    if not p.exists():
        raise t.error(key, f"{str(p)!r} does not exist")
    return p


def _sweeps(t: Table) -> tuple[tuple[str, Mapping[str, tuple[Any, ...]]], ...]:
    return tuple((name, MappingProxyType({k: tuple(v) for k, v in t.table(name).rest().items()}))
                 for name in list(t.data))


def _microbenchmarks(t: Table, base: Path) -> Microbenchmarks:
    sweeps = _sweeps(t.table("sweeps", {}))
    pairs = _sweeps(t.table("pairs", {}))
    folder = t.get("tables", str, None)
    mb = Microbenchmarks(sweeps=sweeps, pairs=pairs, rounds=t.get("rounds", int, 1, minimum=1),
                         reps=t.get("reps", int, 5, minimum=1), warmup=t.get("warmup", int, 2, minimum=0),
                         folder=_existing(base / folder, t, "tables") if folder else None,
                         files=tuple(t.get("files", list, [])))
    t.finish()
    return mb


def _runs(t: Table) -> RunSettings:
    prewarm = t.get("prewarm_frames", int, -1, minimum=-1)
    rs = RunSettings(repeats=t.get("repeats", int, 1, minimum=1),
                     run_seconds=t.get("run_seconds", float, 0.0, minimum=0),
                     prewarm_frames=None if prewarm < 0 else prewarm,
                     max_frames=t.get("max_frames", int, 2000, minimum=1),
                     steady_window=t.get("steady_window", bool, False))
    t.finish()
    return rs


def _pass_kinds(t: Table, key: str) -> tuple[str, ...]:
    """The list at `key`, each a pass kind of the cost model."""
    kinds = t.get(key, list, [])
    unknown = [k for k in kinds if k not in WORK_TERMS]
    if unknown:
        raise t.error(key, f"unknown pass kind(s) {unknown}; known: {sorted(WORK_TERMS)}")
    return tuple(kinds)


def _recipe(t: Table, base: Path) -> Recipe:
    copy_t = t.table("copy_from", {})
    copy_profile = copy_t.get("profile", str, None)
    grid_t = t.table("host_grid", {})
    gpus = t.get("run_fit_gpus", int, 0, minimum=0)
    terms = t.get("run_fit_terms", list, None)
    recipe = Recipe(
        base=t.get("base", str, "profile", choices=("profile", "machine")),
        host_copy_table=t.get("host_copy_table", str, None),
        copy_from=_existing(base / copy_profile, copy_t, "profile") if copy_profile else None,
        copy_costs=tuple(copy_t.get("costs", list, [])), copy_host=tuple(copy_t.get("host", list, [])),
        run_fitted=tuple(t.get("run_fitted", list, [])), run_fit_gpus=gpus or None,
        run_fit_terms=tuple(terms) if terms is not None else None,
        run_fit_alone=_pass_kinds(t, "run_fit_alone"),
        task_gap=t.get("task_gap", bool, False),
        host_copy_wake=t.get("host_copy_wake", bool, False),
        busy_wake=t.get("busy_wake", bool, False),
        copy_setup=t.get("copy_setup", bool, False),
        host_grid=MappingProxyType({k: tuple(grid_t.get(k, list)) for k in list(grid_t.data)}),
        host_grid_level=t.get("host_grid_level", str, "prediction", choices=("prediction", "replay")))
    copy_t.finish()
    grid_t.finish()
    return recipe


def _entries(t: Table, base: Path) -> tuple[Entry, ...]:
    out = []
    for c in (t.tables("config") if t.has("config") else []):
        out.append(Entry(c.get("name", str), _existing(base / c.get("experiment", str), c, "experiment"),
                         tuple(c.get("set", list, []))))
        c.finish()
    return tuple(out)


def _folder(t: Table, base: Path) -> Path | None:
    runs = t.get("runs", str, None)
    return _existing(base / runs, t, "runs") if runs else None
