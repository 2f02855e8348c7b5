"""Experiments: a profile, a scene and a schedule choice, read from TOML with overrides.

An experiment file names its profile by a path relative to itself. Overrides are dotted keys
(``schedule.gpus=4``) applied to the raw TOML before validation, so they are checked exactly
like values written in the file.
"""
from __future__ import annotations

import copy
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from mgpusim.model.errors import InputError
from mgpusim.model.overrides import parse_overrides, parse_value, set_dotted, split_profile
from mgpusim.model.profile import HardwareProfile, load_profile, require_gpus
from mgpusim.model.scene import Scene, parse_scene
from mgpusim.model.toml_checks import Table, read_toml
from mgpusim.model.work_terms import COMMON_PARAMS, PARAM_BOUNDS, PASS_PARAMS, REQUIRED_PARAMS
from mgpusim.schedules.registry import ScheduleConfig, parse_schedule_config


@dataclass(frozen=True)
class Experiment:
    name: str
    file: str
    profile: HardwareProfile
    scene: Scene
    schedule: ScheduleConfig
    raw: Mapping[str, Any]
    #: The hardware what-ifs applied to the profile (``profile.`` overrides, full keys).
    profile_overrides: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


#: The most experiments :func:`load_experiment` keeps to hand back while their files are unchanged.
LOADED_KEPT = 64
#: (file, cwd, overrides, profile argument) -> (profile reference, its resolved file, each file
#: read and the digest of its bytes, the experiment)
_LOADED: dict[tuple, tuple[Path, Path, tuple[tuple[Path, bytes], ...], "Experiment"]] = {}


def load_experiment(path: str | Path, overrides: Mapping[str, Any] | None = None,
                    profile: HardwareProfile | str | Path | None = None) -> Experiment:
    """Read an experiment file, apply `overrides` (dotted key -> value) and validate it all.
    Keys under ``profile.`` change the hardware profile it names (hardware what-ifs).

    The same call on files whose bytes are unchanged (a digest of each, the experiment's and
    its profile's, the profile found again where the experiment names it) returns the
    experiment it returned before. Why: an experiment is a frozen value, and simulate() keeps
    what it derives from one (program, effects, the recurrence's model) per experiment object,
    so a script that loads a file again and simulates it pays only for the run."""
    key = _loaded_key(path, overrides, profile)
    held = _LOADED.get(key) if key is not None else None
    if held is not None and _unchanged(*held[:3], Path(path).parent):
        return held[3]
    exp = _load_experiment(Path(path), overrides, profile)
    if key is not None:
        ref = Path(profile) if isinstance(profile, (str, Path)) else Path(str(exp.raw.get("profile", "")))
        source = Path(exp.profile.source)
        files = tuple((f, _digest(f)) for f in (Path(path), source))
        if len(_LOADED) >= LOADED_KEPT:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = (ref, source, files, exp)
    return exp


def _loaded_key(path: str | Path, overrides: Mapping[str, Any] | None, profile: Any) -> tuple | None:
    """What a loaded experiment is kept under (None: not kept, e.g. a profile object given)."""
    if profile is not None and not isinstance(profile, (str, Path)):
        return None
    try:
        return (str(path), os.getcwd(), repr(sorted((overrides or {}).items())), str(profile))
    except (OSError, TypeError):  # no working folder; overrides whose keys do not sort
        return None


def _unchanged(ref: Path, source: Path, files: tuple[tuple[Path, bytes], ...], base: Path) -> bool:
    """Whether the files an experiment was read from are as they were, its profile still the
    file its reference finds."""
    try:
        if _resolve(ref, base, "") != source:
            return False
        return all(_digest(f) == digest for f, digest in files)
    except (InputError, OSError):
        return False


def _digest(path: Path) -> bytes:
    return hashlib.blake2b(path.read_bytes(), digest_size=16).digest()


def _load_experiment(path: Path, overrides: Mapping[str, Any] | None,
                     profile: HardwareProfile | str | Path | None) -> Experiment:
    """load_experiment's reading and validation, with nothing kept."""
    data = copy.deepcopy(read_toml(path))
    experiment_overrides, profile_overrides = split_profile(overrides)
    for key, value in experiment_overrides.items():
        set_dotted(data, key, value, str(path))
    return parse_experiment(data, str(path), base=path.parent, profile=profile,
                            profile_overrides=profile_overrides)


def parse_experiment(data: dict, file: str, base: Path = Path("."),
                     profile: HardwareProfile | str | Path | None = None,
                     profile_overrides: Mapping[str, Any] | None = None) -> Experiment:
    top = Table(data, file)
    if {"gpus", "host"} <= set(data) and not {"scene", "schedule"} & set(data):
        raise InputError("a hardware profile, not an experiment: an experiment has [scene] and "
                         "[schedule] and names its profile (profile = \"...toml\")", file=file)
    name = top.name("name", Path(file).stem)  # the default output folder: out/<name>
    top.get("description", str, "")
    # A profile given by the caller (--profile, what-ifs) replaces the file's reference.
    profile_ref = top.get("profile", str) if profile is None else top.get("profile", str, None)
    if isinstance(profile, HardwareProfile):
        if profile_overrides:
            raise InputError("profile.* overrides change a profile file; this experiment was given "
                             "a profile object", field=f"profile.{next(iter(profile_overrides))}")
        prof = profile
    else:
        prof = load_profile(_resolve(Path(profile) if profile else Path(profile_ref), base, file),
                            profile_overrides)
    scene = parse_scene(top.table("scene"), PASS_PARAMS, COMMON_PARAMS, REQUIRED_PARAMS,
                        PARAM_BOUNDS)
    sched = parse_schedule_config(top.table("schedule"))
    top.finish()
    require_gpus(prof, sched.gpus, file)
    what_if = MappingProxyType({f"profile.{k}": v for k, v in (profile_overrides or {}).items()})
    return Experiment(name, file, prof, scene, sched, data, what_if)


def _resolve(ref: Path, base: Path, file: str) -> Path:
    for candidate in (ref, base / ref):
        try:
            if candidate.is_file():
                return candidate
        except OSError:  # a name too long for the file system, or not a name at all
            continue
    shown = str(ref) if len(str(ref)) <= 80 else str(ref)[:80] + "..."
    raise InputError(f"profile file {shown!r} not found (looked next to the experiment and in the "
                     "current directory)", file=file, field="profile")


__all__ = ["Experiment", "load_experiment", "parse_experiment", "parse_overrides", "parse_value",
           "set_dotted"]
