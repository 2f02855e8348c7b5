"""Which measured runs a study may use: its own, and enough of them, checked before any fit.

Why: a runs folder is given by path, and a user ends up with folders of other studies, empty
ones, copies cut short. Before this check, another study's runs calibrated "from 14 tables"
with none of them, and a validation of no run at all printed a list of configurations and went
on. A runs folder is the study's own when its run folders are named after the study's
configurations, each records the experiment the configuration names (`summary.json`), and
they ran on the card the study's profile was made for (`machine.json`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.profile import load_profile
from mgpusim.model.toml_checks import read_toml
from mgpusim.studies.measuring import RECORD, measured_folder
from mgpusim.studies.study_file import Entry, Study
from mgpusim.validation.measured import TRACE_FILES
from mgpusim.validation.measured_check import read_json_object

#: How many names a message lists before "...".
_SHOWN = 4


@dataclass(frozen=True)
class Coverage:
    """What a runs folder holds of a half's configurations: `missing` names the configurations
    without a run (allowed only when asked; the report lists them first)."""

    root: Path
    missing: tuple[str, ...]


def check_half(study: Study, entries: tuple[Entry, ...], root: Path, option: str,
               allow_missing: bool = False, half: str = "") -> Coverage:
    """`root` holds `study`'s own runs of `entries` (:func:`check_set`): one InputError naming
    `option` and what was expected where it holds none of them or (unless `allow_missing`)
    lacks some. Where `entries` is empty (a study with no held-out half) nothing is required."""
    if not entries:
        return Coverage(root, ())
    names = check_set(study, root, option)
    missing = tuple(e.name for e in entries if e.name not in names)
    which = f"{half} configurations" if half else "configurations"
    if len(missing) == len(entries):
        raise InputError(f"{root} holds none of the {which} of study {study.name} (expected "
                         f"{_listed(e.name for e in entries)})", field=option or None)
    if missing and not allow_missing:
        raise InputError(f"{root} lacks the runs of {len(missing)} of the {len(entries)} {which} "
                         f"of study {study.name}: {_listed(missing)} (--allow-missing compares "
                         f"those it has and lists the rest)", field=option or None)
    return Coverage(root, missing)


def check_set(study: Study, root: Path, option: str) -> set[str]:
    """The names of `study`'s configurations that `root` holds runs of; one InputError where
    `root` is not a runs folder, was measured for another study (its `study.json`), holds
    none of the study's configurations, or a run records another experiment or card."""
    names = folder_names(root, option)
    _check_record(study, root, option)
    own = {e.name for e in (*study.calibration, *study.held_out)}
    _refuse_foreign(study, root, names, own, option)
    entries = {e.name: e for e in (*study.calibration, *study.held_out)}
    for name in sorted(names & own):
        check_provenance(study, entries[name], root, option)
    return names & own


def _check_record(study: Study, root: Path, option: str) -> None:
    record = root / RECORD
    if not run_archive.is_file(record):
        return
    name = read_json_object(record).get("study")
    if isinstance(name, str) and name != study.name:
        raise InputError(f"{root} holds the runs of study {name!r}, not of {study.name!r}",
                         file=str(record), field=option or None)


def folder_names(root: Path, option: str) -> set[str]:
    """The configuration folders a runs folder holds (on disk or packed in its archive); one
    InputError where `root` is missing, a file or holds no measured run."""
    if root.is_file():
        raise InputError(f"{root} is a file; expected a folder of measured runs (one folder per "
                         f"configuration)", field=option or None)
    if not run_archive.is_folder(root):
        hint = "" if option else " (measure them with `mgpusim study measure`, or give --runs)"
        raise InputError(f"no such runs folder: {root}{hint}", field=option or None)
    names = {_top(run, root) for run in run_archive.runs_in(root)}
    if root.is_dir():  # runs on disk, whatever their trace's format
        names |= {d.name for d in root.iterdir() if d.is_dir() and _has_trace(root, d.name)}
    names.discard("")
    if not names:
        raise InputError(f"{root} holds no measured run (expected one folder per configuration, "
                         f"each with a trace and summary.json)", field=option or None)
    return names


def _has_trace(root: Path, name: str) -> bool:
    folder = measured_folder(root, name)
    return any(run_archive.is_file(folder / f) for f in TRACE_FILES)


def _refuse_foreign(study: Study, root: Path, names: set[str], own: set[str], option: str) -> None:
    """A folder that holds runs, none of them of the study's configurations, is another
    study's. (Runs of more configurations than the study has are let through: a smaller study
    may draw on a larger folder.)"""
    if not names & own:
        raise InputError(f"{root} holds runs of configurations that study {study.name} does not "
                         f"have ({_listed(sorted(names))}): the runs of another study? (expected "
                         f"{_listed(sorted(own))})", field=option or None)


def check_provenance(study: Study, entry: Entry, root: Path, option: str) -> None:
    """The run of `entry` records its experiment's name and ran on the study's card."""
    folder = measured_folder(root, entry.name)
    summary = folder / "summary.json"
    if run_archive.is_file(summary):
        recorded = read_json_object(summary).get("config", {})
        ran = recorded.get("experiment") if isinstance(recorded, dict) else None
        expected = experiment_name(entry.experiment)
        if isinstance(ran, str) and expected is not None and ran != expected:
            raise InputError(f"the run of {entry.name} is of experiment {ran!r}, study {study.name}'s "
                             f"configuration is of {expected!r}: the runs of another study?",
                             file=str(summary), field=option or None)
    machine = folder / "machine.json"
    card = study_card(study.profile)
    if card is not None and run_archive.is_file(machine):
        ran_on = _run_card(read_json_object(machine))
        if ran_on is not None and card_family(ran_on) != card_family(card):
            raise InputError(f"the run of {entry.name} ran on {ran_on}; study {study.name}'s profile "
                             f"is of {card}: the runs of another machine?", file=str(machine),
                             field=option or None)


@lru_cache(maxsize=64)
def experiment_name(path: Path) -> str | None:
    """The `name` an experiment file gives itself (None where it gives none)."""
    name = read_toml(path).get("name")
    return name if isinstance(name, str) else None


@lru_cache(maxsize=16)
def study_card(profile: Path) -> str | None:
    """The GPU the study's profile was calibrated on (None where it does not say)."""
    calibrated = load_profile(profile).calibrated_on
    return calibrated.device if calibrated is not None and calibrated.device else None


def card_family(device: str) -> str:
    """A device name without its driver's build details: `llvmpipe (LLVM 15.0.6, 256 bits)`
    is `llvmpipe` on every machine, an NVIDIA card keeps its model."""
    return re.sub(r"\s*\(.*$", "", device).strip().lower()


def _run_card(machine: dict[str, Any]) -> str | None:
    gpus = machine.get("gpus")
    if isinstance(gpus, list) and gpus and isinstance(gpus[0], dict):
        device = gpus[0].get("device")
        return device if isinstance(device, str) and device else None
    return None


def _top(run: Path, root: Path) -> str:
    """The first folder of `run` below `root` (its configuration's)."""
    rel = run.relative_to(root).parts
    return rel[0] if rel else ""


def _listed(names: Iterable[str]) -> str:
    items = list(names)
    shown = ", ".join(items[:_SHOWN])
    return shown + (f", ... ({len(items)} in all)" if len(items) > _SHOWN else "")
