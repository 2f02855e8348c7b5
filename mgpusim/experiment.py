"""Experiments: a profile, a scene and a schedule choice, read from TOML with overrides.

An experiment file names its profile by a path relative to itself. Overrides are dotted keys
(``schedule.gpus=4``) applied to the raw TOML before validation, so they are checked exactly
like values written in the file.
"""
from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from .config import Table, read_toml
from .costs import WORK_TERMS
from .errors import InputError
from .profile import HardwareProfile, load_profile, require_gpus
from .scene import Scene, parse_scene
from .schedules.base import ScheduleConfig, parse_schedule_config


@dataclass(frozen=True)
class Experiment:
    name: str
    file: str
    profile: HardwareProfile
    scene: Scene
    schedule: ScheduleConfig
    raw: Mapping[str, Any]


def load_experiment(path: str | Path, overrides: Mapping[str, Any] | None = None,
                    profile: HardwareProfile | str | Path | None = None) -> Experiment:
    """Read an experiment file, apply `overrides` (dotted key -> value) and validate it all."""
    path = Path(path)
    data = copy.deepcopy(read_toml(path))
    for key, value in (overrides or {}).items():
        set_dotted(data, key, value, str(path))
    return parse_experiment(data, str(path), base=path.parent, profile=profile)


def parse_experiment(data: dict, file: str, base: Path = Path("."),
                     profile: HardwareProfile | str | Path | None = None) -> Experiment:
    top = Table(data, file)
    name = top.get("name", str, Path(file).stem)
    top.get("description", str, "")
    # A profile given by the caller (--profile, what-ifs) replaces the file's reference.
    profile_ref = top.get("profile", str) if profile is None else top.get("profile", str, None)
    if isinstance(profile, HardwareProfile):
        prof = profile
    else:
        prof = load_profile(_resolve(Path(profile) if profile else Path(profile_ref), base, file))
    scene = parse_scene(top.table("scene"), frozenset(WORK_TERMS))
    sched = parse_schedule_config(top.table("schedule"))
    top.finish()
    require_gpus(prof, sched.gpus, file)
    return Experiment(name, file, prof, scene, sched, data)


def _resolve(ref: Path, base: Path, file: str) -> Path:
    for candidate in (ref, base / ref):
        if candidate.is_file():
            return candidate
    raise InputError(f"profile file {str(ref)!r} not found (looked next to the experiment and in the "
                     "current directory)", file=file, field="profile")


def parse_value(text: str) -> Any:
    """A --set value as TOML (numbers, booleans, quoted strings, lists); bare words as strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def set_dotted(data: dict, key: str, value: Any, file: str) -> None:
    """Set `key` (dotted; a number indexes an array of tables, e.g. scene.passes.0.iterations)."""
    parts = key.split(".")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            child = node[_index(node, part, key, file)]
        else:
            child = node.setdefault(part, {})
        if not isinstance(child, (dict, list)):
            raise InputError(f"cannot set {key!r}: {'.'.join(parts[:i + 1])} is not a table",
                             file=file, field=key)
        node = child
    if isinstance(node, list):
        node[_index(node, parts[-1], key, file)] = value
    else:
        node[parts[-1]] = value


def _index(items: list, part: str, key: str, file: str) -> int:
    if not part.isdigit() or int(part) >= len(items):
        raise InputError(f"cannot set {key!r}: {part!r} is not an index below {len(items)}",
                         file=file, field=key)
    return int(part)


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--set expects key=value, got {item!r}")
        key, _, text = item.partition("=")
        out[key.strip()] = parse_value(text.strip())
    return out

