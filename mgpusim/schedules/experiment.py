"""Experiments: a profile, a scene and a schedule choice, read from TOML with overrides.

An experiment file names its profile by a path relative to itself. Overrides are dotted keys
(``schedule.gpus=4``) applied to the raw TOML before validation, so they are checked exactly
like values written in the file.
"""
from __future__ import annotations

import copy
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


def load_experiment(path: str | Path, overrides: Mapping[str, Any] | None = None,
                    profile: HardwareProfile | str | Path | None = None) -> Experiment:
    """Read an experiment file, apply `overrides` (dotted key -> value) and validate it all.
    Keys under ``profile.`` change the hardware profile it names (hardware what-ifs)."""
    path = Path(path)
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
