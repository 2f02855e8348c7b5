"""One experiment file loaded under many sets of overrides: parsed once, overridden in memory.

Why: a sweep loads its experiment once per point. :func:`~mgpusim.schedules.experiment.load_experiment`
reads and parses the experiment's TOML and its profile's every time (about 1.5 ms of a point's
few at the analytic level). :class:`ExperimentLoader` gives the same :class:`Experiment` for
the same overrides, checked the same way with the same errors, but reads the experiment file
once, resolves its profile reference once, reads each profile file once and validates each
profile (file and ``profile.`` overrides, set on a copy of its table as `load_profile` sets
them) once, and keeps a hash of each file's bytes as read (:meth:`ExperimentLoader.inputs`:
what a sweep's points are known by, so that an edited profile is a new point). An
experiment's own overrides are set on a copy of the parsed table (a deep copy of each
top-level table an override reaches, the others shared: validation only reads them),
which is then validated exactly as `parse_experiment` validates a file's (the same steps in
the same order; a test checks both give equal experiments, or the same error, over every
shipped experiment and many overrides). A profile that fails to load fails every later load
the same way. Files are read when first needed: a file edited during a sweep is not seen (a
sweep's points are known by the bytes of the files it read before its first point ran).
"""
from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import os
from collections import OrderedDict
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable, Iterable, Mapping, TypeVar

from mgpusim.model.errors import InputError
from mgpusim.model.overrides import set_dotted, split_profile
from mgpusim.model.profile import HardwareProfile, apply_profile_overrides, parse_profile, require_gpus
from mgpusim.model.scene import parse_scene
from mgpusim.model.toml_checks import Table, read_input_bytes, read_toml
from mgpusim.model.work_terms import COMMON_PARAMS, PARAM_BOUNDS, PASS_PARAMS, REQUIRED_PARAMS
from mgpusim.schedules.experiment import Experiment, _resolve
from mgpusim.schedules.registry import parse_schedule_config

T = TypeVar("T")


def _once(cache: dict[Any, Any], key: Any, compute: Callable[[], T]) -> T:
    """`compute()` once per `key`: its value, or the InputError it raised, kept and given
    again (raised again) every later time."""
    if key not in cache:
        try:
            cache[key] = compute()
        except InputError as exc:
            cache[key] = exc
    found = cache[key]
    if isinstance(found, InputError):
        raise found.with_traceback(None)
    return found


class ExperimentLoader:
    """``loader.load(overrides)`` is ``load_experiment(path, overrides)``, parsed once (see the
    module doc)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.file = str(self.path)
        self._raw: dict[str, dict[str, Any] | InputError] = {}
        self._refs: dict[str, Path | InputError] = {}
        self._profiles: dict[tuple, HardwareProfile | InputError] = {}
        self._profile_tables: dict[str, dict[str, Any] | InputError] = {}
        #: file -> sha256 of its bytes, for every input file read (experiment, profiles)
        self._digests: dict[str, str] = {}
        #: (table, its overrides) -> the parsed scene or schedule, or its error
        self._sections: OrderedDict[tuple, Any] = OrderedDict()

    def load(self, overrides: Mapping[str, Any] | None = None) -> Experiment:
        raw = self._table()
        data = dict(raw)
        experiment_overrides, profile_overrides = split_profile(overrides)
        for top in {key.split(".", 1)[0] for key in experiment_overrides}:
            if top in raw:
                data[top] = _copied(raw[top])
        for key, value in experiment_overrides.items():
            set_dotted(data, key, value, self.file)
        return self._parse(data, profile_overrides, experiment_overrides)

    def profile(self, ref: str, overrides: Mapping[str, Any]) -> HardwareProfile:
        """The profile `ref` names (relative to the experiment, else the current directory)
        with `overrides` (keys relative to the profile), parsed once per distinct set."""
        path = self._resolved(ref)
        key = (str(path), tuple((k, _canonical(v)) for k, v in overrides.items()))
        return _once(self._profiles, key, lambda: self._load_profile(path, overrides))

    def _load_profile(self, path: Path, overrides: Mapping[str, Any]) -> HardwareProfile:
        """`load_profile(path, overrides)` with the file's TOML parsed once: its steps (the
        overrides applied to a copy, then the whole validated)."""
        table = _once(self._profile_tables, str(path), lambda: self._read(path))
        data = apply_profile_overrides(table, overrides, str(path)) if overrides else table
        return parse_profile(data, str(path))

    def _table(self) -> dict[str, Any]:
        return _once(self._raw, "", lambda: self._read(self.path))

    def _read(self, path: Path) -> dict[str, Any]:
        """`read_toml(path)`, with the hash of the file's bytes kept (read first: a file
        edited between the two reads is known by its older bytes, and read again next sweep)."""
        with contextlib.suppress(InputError):  # read_toml says what is wrong with it
            self._digests[str(path)] = hashlib.sha256(read_input_bytes(path, "a TOML file")).hexdigest()
        return read_toml(path)

    def _input_name(self, path: Path) -> str:
        """How :meth:`inputs` names a profile file: its path relative to the experiment's
        folder (the same wherever the sweep is started from)."""
        return os.path.relpath(path.resolve(), self.path.resolve().parent)

    def inputs(self, refs: Iterable[str] = ()) -> dict[str, str]:
        """{file: sha256 of its bytes as read} of the experiment and each profile file `refs`
        name (read now if no load has yet; a reference that does not resolve or parse is left
        to the point that names it). Why: a point's result depends on them all, so a sweep's
        resume key holds them (an edited profile is a new point, not an old one reused)."""
        self._table()
        out = {"experiment": self._digests[str(self.path)]} if str(self.path) in self._digests else {}
        for ref in refs:
            with contextlib.suppress(InputError):
                path = self._resolved(ref)
                _once(self._profile_tables, str(path), lambda at=path: self._read(at))  # type: ignore[misc]
                if str(path) in self._digests:
                    out[self._input_name(path)] = self._digests[str(path)]
        return dict(sorted(out.items()))

    def _resolved(self, ref: str) -> Path:
        return _once(self._refs, ref, lambda: _resolve(Path(ref), self.path.parent, self.file))

    def _parse(self, data: dict, profile_overrides: Mapping[str, Any],
               overrides: Mapping[str, Any] | None = None) -> Experiment:
        """`parse_experiment(data, file, base=path.parent, profile_overrides=...)`, step for
        step, with the profile from :meth:`profile` and the scene and schedule each parsed once
        per set of `overrides` (the experiment's, as set on `data`) that reach its table
        (:meth:`_section`)."""
        file = self.file
        top = Table(data, file)
        if {"gpus", "host"} <= set(data) and not {"scene", "schedule"} & set(data):
            raise InputError("a hardware profile, not an experiment: an experiment has [scene] and "
                             "[schedule] and names its profile (profile = \"...toml\")", file=file)
        name = top.name("name", Path(file).stem)
        top.get("description", str, "")
        prof = self.profile(top.get("profile", str), profile_overrides)
        scene_table = top.table("scene")
        scene = self._section("scene", overrides, lambda: parse_scene(
            scene_table, PASS_PARAMS, COMMON_PARAMS, REQUIRED_PARAMS, PARAM_BOUNDS))
        schedule_table = top.table("schedule")
        sched = self._section("schedule", overrides, lambda: parse_schedule_config(schedule_table))
        top.finish()
        require_gpus(prof, sched.gpus, file)
        what_if = MappingProxyType({f"profile.{k}": v for k, v in profile_overrides.items()})
        return Experiment(name, file, prof, scene, sched, data, what_if)


    def _section(self, name: str, overrides: Mapping[str, Any] | None, parse: Callable[[], T]) -> T:
        """`parse()` of the table `name` (scene, schedule), once per set of the overrides that
        reach it, in their order (the table is the file's with those set, nothing else: the
        parse of one set is the parse of every load with it, value or error). Why: a sweep's
        points share most of their tables (a grid over the width has one schedule table),
        and parsing one costs a tenth of a point at the analytic level. The SECTIONS_KEPT
        most recently used sets are kept."""
        if overrides is None:
            return parse()
        key = (name, *((k, _canonical(v)) for k, v in overrides.items() if k.split(".", 1)[0] == name))
        found = self._sections.get(key)
        if found is None:
            try:
                found = parse()
            except InputError as exc:
                found = exc
            self._sections[key] = found
            while len(self._sections) > SECTIONS_KEPT:
                self._sections.popitem(last=False)
        else:
            self._sections.move_to_end(key)
        if isinstance(found, InputError):
            raise found.with_traceback(None)
        return found


def _copied(value: Any) -> Any:
    """`copy.deepcopy` of a parsed TOML table: its tables and arrays copied, its values (text,
    numbers, dates: immutable) shared. (deepcopy's memo cost a tenth of a point's load.)"""
    kind = type(value)
    if kind is dict:
        return {k: _copied(v) for k, v in value.items()}
    if kind is list:
        return [_copied(v) for v in value]
    if kind in (str, int, float, bool):
        return value
    return copy.deepcopy(value)


#: Parsed scene and schedule tables a loader keeps (:meth:`ExperimentLoader._section`).
SECTIONS_KEPT = 4096


def _canonical(value: Any) -> str:
    """A value as text that tells apart what TOML tells apart (1, 1.0, true, "1"). (A key of
    this process's caches only: a plain number or text as its repr and type, without json.)"""
    kind = type(value)
    if kind is int or kind is float or kind is bool or kind is str:
        return f"{value!r}{kind.__name__}"
    return json.dumps(value, sort_keys=True, default=repr) + type(value).__name__


#: One loader per experiment file and process (a pool's forked workers inherit the sweep's).
_SHARED: dict[str, ExperimentLoader] = {}


def shared(experiment: str | Path) -> ExperimentLoader:
    """This process's :class:`ExperimentLoader` for `experiment` (by its path as given)."""
    key = str(experiment)
    found = _SHARED.get(key)
    if found is None:
        found = _SHARED[key] = ExperimentLoader(experiment)
    return found


def fresh(experiment: str | Path) -> ExperimentLoader:
    """A new :func:`shared` loader for `experiment`, files read again: what a sweep starts
    with, so that one run after a profile was edited (in the same process: a notebook, a
    test) reads the edited bytes and hashes those into its points."""
    _SHARED.pop(str(experiment), None)
    return shared(experiment)
