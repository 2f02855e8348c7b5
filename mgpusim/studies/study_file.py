"""A study as data: which configurations are measured, which ones calibrate, which are held out.

A study file (TOML) names a profile, the microbenchmarks (sweeps to measure, or a folder of
committed tables), how measured runs are taken, a calibration recipe and two lists of
configurations (an experiment file plus `--set` overrides each). Every path in it is relative
to the file. The lavapipe main job and the NVIDIA validations are studies; adding a machine is
adding a study file.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Sequence

from mgpusim.calibration.measure_tables import MEASURED_PASSES
from mgpusim.io.workers import usable_cores
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_GPUS
from mgpusim.model.profile import HardwareProfile, HostProfile
from mgpusim.model.shipped_files import PACKAGE
from mgpusim.model.toml_checks import Table, did_you_mean, read_toml
from mgpusim.model.work_terms import WORK_TERMS, work_terms
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_overrides

#: A key with no default: its absence is an error.
_REQUIRED = object()


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
    """Pass sweeps to measure (`rounds` x `reps` repetitions each; a pass may have several, as
    the mesh has our torus and vmgpu's culled sphere), or committed `tables`.
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
    of another GPU (`busy_wake`); a grid search of host effects. `host_pcie`: the host side of
    PCIe from the copy tables' rows with several GPUs copying at once (step 1)."""

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
    #: the host side of PCIe per direction (host.pcie_d2h_gbps / pcie_h2d_gbps) from the copy
    #: tables' rows with the most GPUs copying at once: the sum of their rates
    host_pcie: bool = False
    host_grid: Mapping[str, tuple[Any, ...]] = field(default_factory=lambda: MappingProxyType({}))
    #: what the grid search scores: the prediction's frame-time error, or the replay's (the
    #: timeline on the runs' own durations, so that cost errors cannot set host effects)
    host_grid_level: str = "prediction"


@dataclass(frozen=True)
class Target:
    """A level's target: |simulated / measured - 1| of the frame time, median and worst over
    the configurations of the half the verdict is on (docs/validation.md, "The verdict")."""

    median: float
    worst: float


@dataclass(frozen=True)
class Targets:
    """What the verdict checks (None: that level is reported but not judged): the replay (the
    model's timeline on each run's own task durations) and the prediction (the cost model)."""

    replay: Target | None = None
    prediction: Target | None = None


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
    #: the verdict's targets (`[targets]`; none: the errors are reported, no target judged)
    targets: Targets = Targets()

    def lavapipe_threads(self) -> int | None:
        """LP_NUM_THREADS of every lavapipe GPU the study measures, from this machine's cores.

        Why more threads than cores: with one rasterizer thread per core a lavapipe mesh pass
        runs in one of two modes at random, for tens of frames at a time, 1.3x apart (both
        threads busy, or one doing nearly all the bins while the other waits); with twice as
        many threads the bins spread evenly and every run lands in the fast mode."""
        if self.lavapipe_threads_per_core is None:
            return None
        return max(1, round(self.lavapipe_threads_per_core * usable_cores()))

    def entries(self, held_out: bool = True) -> tuple[Entry, ...]:
        return self.calibration + (self.held_out if held_out else ())


def load_study(path: Path | str) -> Study:
    """Read and check a study file, all of it, before any work: types, paths (relative to the
    file, existing; table files inside `tables`), configuration names that are plain file names,
    pass kinds and work terms, and every configuration's experiment with its `set` (loaded on
    the study's profile). Every error names the file and the field."""
    path = Path(path)
    top = Table(read_toml(path), str(path))
    if top.has("kind"):  # another kind of study (a frame-time study of an external renderer)
        raise top.error("kind", f"{top.data['kind']!r}: this study's measurements are not our "
                                "runner's runs; `mgpusim study validate` compares them, the other "
                                "steps do not apply")
    base = path.parent
    cal, held = top.table("calibration", {}), top.table("held_out", {})
    study = Study(
        name=top.name("name", path.stem),
        file=path,
        description=top.get("description", str, ""),
        profile=_path(top, "profile", base),
        microbenchmarks=_microbenchmarks(top.table("microbenchmarks", {}), base),
        runs=_runs(top.table("runs", {})),
        recipe=_recipe(cal, base),
        calibration=_entries(cal, base),
        held_out=_entries(held, base),
        calibration_runs=_path(cal, "runs", base, None, folder=True),
        held_out_runs=_path(held, "runs", base, None, folder=True),
        lavapipe_threads_per_core=top.get("lavapipe_threads_per_core", float, None, minimum=0.25,
                                          maximum=16),
        targets=_targets(top.table("targets", {})),
    )
    cal.finish()
    held.finish()
    top.finish()
    names = [e.name for e in study.entries()]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"configuration names must be unique, repeated: {', '.join(dup)}", file=str(path))
    _check_host_copy_table(study, cal)
    _check_entries_load(study)
    return study


def _path(t: Table, key: str, base: Path, default: Any = _REQUIRED, *, folder: bool = False) -> Any:
    """The path at `key`, relative to the study file (`base`), which must exist (as a folder
    when `folder`: on disk, or one a packed archive above it holds, see run_archive). Why
    relative: a study and its data travel together (a checkout, a copy)."""
    text = t.get(key, str) if default is _REQUIRED else t.get(key, str, default)
    if text is None:
        return None
    if not text.strip() or "\0" in text:
        raise t.error(key, f"expected a path relative to the study file, got {text!r}")
    if Path(text).is_absolute():
        raise t.error(key, f"must be relative to the study file, got the absolute path {text!r}")
    p = base / text
    if not (run_archive.is_folder(p) if folder else p.exists() or run_archive.is_file(p)):
        raise t.error(key, f"{str(p)!r} does not exist{' (or is not a folder)' if folder else ''}"
                           f"{_checkout_hint(text)}")
    return p


def _checkout_hint(text: str) -> str:
    """Why a shipped study's committed data can be missing: an installed wheel carries the
    experiments and profiles but not the repository's `data/` (measured runs, tables)."""
    if "data" in Path(text).parts and not (PACKAGE.parent / "data").is_dir():
        return ("; the measured data lies in the repository's data/ folder, which an installed "
                "package does not carry: run from a checkout of the repository")
    return ""


def _strings(t: Table, key: str, default: Any = _REQUIRED, *, empty: bool = False) -> Any:
    """A list of strings at `key` (None or `default` if absent); an empty list is refused
    unless `empty`, since it would silently switch a step off or mean "all"."""
    items = t.get(key, list) if default is _REQUIRED else t.get(key, list, default)
    if items is None or items is default:
        return items
    if not items and not empty:
        raise t.error(key, "is an empty list: leave the key out instead")
    for i, item in enumerate(items):
        if not isinstance(item, str):
            raise t.error(f"{key}[{i}]", f"expected a string, got {item!r}")
    return tuple(items)


def _inside(t: Table, key: str, folder: Path, name: str) -> Path:
    """`folder / name` for a file named by the study inside one of its folders: relative, no
    `..`, existing."""
    if not name.strip() or "\0" in name or Path(name).is_absolute() or ".." in Path(name).parts:
        raise t.error(key, f"must name a file inside {str(folder)!r} (relative, no '..'), got {name!r}")
    p = folder / name
    if not run_archive.is_file(p):  # on disk, or in the folder's packed archive
        raise t.error(key, f"{str(p)!r} does not exist (or is not a file)")
    return p


def _values(t: Table, key: str, kinds: tuple[type, ...] = (int, float, str, bool)) -> tuple[Any, ...]:
    """A non-empty list of scalar values (a sweep's or the grid's): a lone value, an empty list
    or a nested table is refused, where it would be a sweep of nothing or of one letter each."""
    values = t.data[key]
    t.get(key, list)
    if not values:
        raise t.error(key, "is an empty list: a sweep needs at least one value")
    for i, v in enumerate(values):
        if not isinstance(v, kinds) or (isinstance(v, float) and not math.isfinite(v)) \
                or (bool not in kinds and isinstance(v, bool)):
            names = "numbers" if str not in kinds else "numbers, strings or true/false"
            raise t.error(f"{key}[{i}]", f"expected {names}, got {v!r}")
    return tuple(values)


def _sweeps(t: Table) -> tuple[tuple[str, Mapping[str, tuple[Any, ...]]], ...]:
    out = []
    for name in list(t.data):
        if name not in MEASURED_PASSES:
            raise t.error(name, f"not a pass of the measure library{did_you_mean(name, MEASURED_PASSES)}; "
                                f"it has {', '.join(MEASURED_PASSES)}")
        # one sweep, or several of one pass (an array: their products measured one after another)
        several = isinstance(t.data[name], list)
        for sweep in (t.tables(name) if several else [t.table(name)]):
            if not sweep.data:
                raise sweep.error("", "an empty sweep: give each parameter's values")
            out.append((name, MappingProxyType({k: _values(sweep, k) for k in list(sweep.data)})))
    return tuple(out)


def _microbenchmarks(t: Table, base: Path) -> Microbenchmarks:
    sweeps = _sweeps(t.table("sweeps", {}))
    pairs = _sweeps(t.table("pairs", {}))
    folder = _path(t, "tables", base, None, folder=True)
    files = _strings(t, "files", None)
    if (folder is None) != (files is None):
        raise t.error("files" if folder is None else "tables",
                      "`tables` (a folder) and `files` (the tables in it) go together")
    mb = Microbenchmarks(sweeps=sweeps, pairs=pairs, rounds=t.get("rounds", int, 1, minimum=1),
                         reps=t.get("reps", int, 5, minimum=1), warmup=t.get("warmup", int, 2, minimum=0),
                         folder=folder,
                         files=tuple(str(_inside(t, f"files[{i}]", folder, f).relative_to(folder))
                                     for i, f in enumerate(files or ())))
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


def _targets(t: Table) -> Targets:
    """`[targets]`: per level (`replay`, `prediction`) a table `{median = F, worst = F}`, the
    fractions (0.05 = 5 %) its median and worst |frame-time error| must not pass."""
    levels: dict[str, Target | None] = {}
    for level in ("replay", "prediction"):
        present = t.has(level)
        sub = t.table(level, {})  # read either way: a misspelt level gets the closest name
        if not present:
            levels[level] = None
            continue
        median = sub.get("median", float, minimum=0.0, maximum=10.0)
        worst = sub.get("worst", float, minimum=0.0, maximum=10.0)
        if worst < median:
            raise sub.error("worst", f"the worst may not be under the median ({worst} < {median})")
        sub.finish()
        levels[level] = Target(median, worst)
    t.finish()
    return Targets(**levels)


def _pass_kinds(t: Table, key: str) -> tuple[str, ...]:
    """The list at `key`, each a pass kind of the cost model."""
    kinds = _strings(t, key, ())
    unknown = [k for k in kinds if k not in WORK_TERMS]
    if unknown:
        raise t.error(key, f"unknown pass kind(s) {unknown}{did_you_mean(unknown[0], WORK_TERMS)}; "
                           f"known: {', '.join(sorted(WORK_TERMS))}")
    return kinds


def _work_terms(t: Table, key: str) -> tuple[str, ...] | None:
    """The list at `key`, each a work term some pass kind has (`pixel`, `triangle`, ...)."""
    terms = _strings(t, key, None)
    known = sorted({term for kind in WORK_TERMS for term in work_terms(kind)})
    unknown = [x for x in terms or () if x not in known]
    if unknown:
        raise t.error(key, f"unknown work term(s) {unknown}{did_you_mean(unknown[0], known)}; "
                           f"known: {', '.join(known)}")
    return terms


def _recipe(t: Table, base: Path) -> Recipe:
    copy_t = t.table("copy_from", {})
    copy_profile = _path(copy_t, "profile", base, None)
    costs, host = _strings(copy_t, "costs", ()), _strings(copy_t, "host", ())
    _check_copy_from(copy_t, copy_profile, costs, host)
    grid_t = t.table("host_grid", {})
    gpus = t.get("run_fit_gpus", int, 0, minimum=0, maximum=MAX_GPUS)
    recipe = Recipe(
        base=t.get("base", str, "profile", choices=("profile", "machine")),
        host_copy_table=t.get("host_copy_table", str, None),
        copy_from=copy_profile, copy_costs=costs, copy_host=host,
        run_fitted=_pass_kinds(t, "run_fitted"), run_fit_gpus=gpus or None,
        run_fit_terms=_work_terms(t, "run_fit_terms"),
        run_fit_alone=_pass_kinds(t, "run_fit_alone"),
        task_gap=t.get("task_gap", bool, False),
        host_copy_wake=t.get("host_copy_wake", bool, False),
        busy_wake=t.get("busy_wake", bool, False),
        copy_setup=t.get("copy_setup", bool, False),
        host_pcie=t.get("host_pcie", bool, False),
        host_grid=MappingProxyType({k: _values(grid_t, _host_key(grid_t, k), (int, float))
                                    for k in list(grid_t.data)}),
        host_grid_level=t.get("host_grid_level", str, "prediction", choices=("prediction", "replay")))
    copy_t.finish()
    grid_t.finish()
    return recipe


def _host_key(t: Table, key: str) -> str:
    """A key of a profile's `[host]` table (the grid searches over host effects)."""
    known = [f.name for f in fields(HostProfile)]
    if key not in known:
        raise t.error(key, f"not a host key of a profile{did_you_mean(key, known)}")
    return key


def _check_copy_from(t: Table, profile: Path | None, costs: tuple[str, ...], host: tuple[str, ...]) -> None:
    """The cost kinds and host keys to copy exist in the profile they are copied from."""
    if profile is None:
        if costs or host:
            raise t.error("costs" if costs else "host", "needs copy_from.profile, the profile to copy from")
        return
    other = Table(read_toml(profile), str(profile))
    gpus = other.data.get("gpus")
    have = gpus[0].get("costs", {}) if isinstance(gpus, list) and gpus and isinstance(gpus[0], dict) else {}
    host_t = other.data.get("host")
    host_t = host_t if isinstance(host_t, dict) else {}
    for key, wanted, present in (("costs", costs, have), ("host", host, host_t)):
        missing = [w for w in wanted if w not in present]
        if missing:
            raise t.error(key, f"{missing[0]!r} is not in {str(profile)!r}"
                               f"{did_you_mean(missing[0], present)}")


def _check_host_copy_table(study: Study, cal: Table) -> None:
    """The host copy table is one the calibration can read: a file inside `tables` (where it
    is read from, listed in `files` or not), or the table a sweep writes (`<pass>.csv`)."""
    name = study.recipe.host_copy_table
    mb = study.microbenchmarks
    if name is None:
        return
    if mb.folder is not None:
        _inside(cal, "host_copy_table", mb.folder, name)
        return
    known = [f"{p}.csv" for p in mb.passes()]
    if name not in known:
        raise cal.error("host_copy_table", f"{name!r} is not a table the study measures "
                                           f"({', '.join(known) or 'none'}){did_you_mean(name, known)}")


def _entries(t: Table, base: Path) -> tuple[Entry, ...]:
    out = []
    for c in (t.tables("config") if t.has("config") else []):
        sets = _strings(c, "set", (), empty=True)
        for i, item in enumerate(sets):
            try:
                parse_overrides([item])
            except InputError as exc:
                raise c.error(f"set[{i}]", exc.detail) from None
        out.append(Entry(c.name("name"), _path(c, "experiment", base), sets))
        c.finish()
    return tuple(out)


def _check_entries_load(study: Study) -> None:
    """Every configuration's experiment, with its `set`, loads on the study's profile: a
    misspelt key is refused now, not after the microbenchmarks have been measured."""
    for half, entries in (("calibration", study.calibration), ("held_out", study.held_out)):
        for i, e in enumerate(entries):
            try:
                e.load(study.profile)
            except InputError as exc:
                raise InputError(f"configuration {e.name!r} does not load: {exc}", file=str(study.file),
                                 field=f"{half}.config[{i}]") from None
