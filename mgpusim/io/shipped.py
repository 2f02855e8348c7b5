"""The experiments and hardware profiles shipped with mgpusim, wherever it is installed.

In a checkout they are the repository's `experiments/` and `hardware_profiles/`; a wheel
carries them inside the package (`mgpusim/experiments/`, `mgpusim/hardware_profiles/`, see
setup.py), where an experiment's relative profile path still resolves. So a command given a
name (`sort_first_tc1`, `lavapipe/sort_first`) or a checkout path (`experiments/afr_tc1.toml`)
that is not a file here finds the shipped file instead.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mgpusim.model.errors import InputError
from mgpusim.model.shipped_files import shipped_dir
from mgpusim.model.toml_checks import read_toml


@dataclass(frozen=True)
class Example:
    """One shipped experiment, as `mgpusim examples` lists it."""

    name: str  # relative to experiments/, without .toml: what commands accept
    path: Path
    schedule: str
    gpus: int
    description: str


def examples() -> list[Example]:
    """Every shipped experiment file (a table with [schedule]), sorted by name."""
    root = shipped_dir("experiments")
    out = []
    for path in sorted(root.rglob("*.toml")):
        data = read_toml(path)  # a broken shipped file is an input error naming it
        schedule = data.get("schedule")
        if not isinstance(schedule, dict):  # e.g. a list of configurations, not an experiment
            continue
        out.append(Example(path.relative_to(root).with_suffix("").as_posix(), path,
                           str(schedule.get("name", "?")), int(schedule.get("gpus", 1)),
                           str(data.get("description", ""))))
    return out


def resolve_experiment(ref: str | Path) -> Path:
    """A path as given if something is there (the loader says what is wrong with a folder or
    an unreadable file); else the shipped experiment (or study file: they live among the
    experiments) it names, so that a checkout's path works from a wheel install too."""
    path = Path(ref)
    if path.exists():
        return path
    root = shipped_dir("experiments")
    text = path.as_posix()
    rel = text.split("experiments/", 1)[1] if "experiments/" in text else text
    for candidate in (root / rel, root / f"{rel}.toml"):
        if candidate.is_file():
            return candidate
    raise InputError("file not found, nor a shipped experiment of that name "
                     "(`mgpusim examples` lists them)", file=str(ref))
