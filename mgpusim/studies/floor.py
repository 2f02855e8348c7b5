"""How far one configuration's replay error moves between sets of runs of the same study: the
floor the runs put under any model's replay (`mgpusim study floor`).

Why: the replay gives every task the duration the run measured for it, so its error is the
timeline's, whatever the machine's speed. But the hand-offs (a thread waking on another GPU's
fence) are not the same from one set of runs to the next where the kernel wakes threads late
on busy cores, so one configuration's replay error moves between sets that the replay cannot
tell apart. No model that gives a configuration one timeline can be closer, in every set, than
half the range its error spans over the sets.

Each set is validated offline, tables only (both halves of the study), with one profile or
each set's own (a main job's `profile.toml` beside its `runs/`). Pure tables in, tables out;
the command writes and prints them.
"""
from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path

import pandas as pd

from mgpusim.model.errors import InputError
from mgpusim.studies import pipeline as pipeline
from mgpusim.studies import run_sets
from mgpusim.studies.study_file import Study

#: (title, held out) of the study's two halves
HALVES = ((pipeline.CALIBRATION_TITLE, False), (pipeline.HELD_OUT_TITLE, True))
ERROR_COLUMNS = ["set", "half", "config", "replay", "prediction"]


def check_sets(study: Study, sets: list[Path]) -> None:
    """Every set is a runs folder of `study`'s own (:func:`mgpusim.studies.run_sets.check_set`)
    and no two hold the same runs: a set given twice, or a copy of one, would show a floor of
    0 % that no measurement made."""
    seen: dict[str, Path] = {}
    for runs in sets:
        run_sets.check_set(study, runs, "--runs")
        digest = content_digest(runs)
        if digest in seen:
            raise InputError(f"{seen[digest]} and {runs} hold the same runs: a floor needs sets "
                             f"measured apart", field="--runs")
        seen[digest] = runs


def content_digest(root: Path) -> str:
    """A hash of every file below `root`, by path and bytes (the profile beside it is not in)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def set_profile(runs: Path, profile: Path | None) -> Path:
    """The profile to replay a set with: the one given, else the set's own beside it."""
    if profile is not None:
        return profile
    own = runs.parent / "profile.toml"
    if not own.is_file():
        raise InputError(f"{runs}: no profile.toml beside it; give --profile", field="--runs")
    return own


def set_names(sets: list[Path]) -> list[str]:
    """Each set's name in the tables: a main job's folder for its `runs/`, else the folder; the
    paths themselves where two would share a name."""
    names = [runs.parent.name if runs.name == "runs" else runs.name for runs in sets]
    return names if len(set(names)) == len(names) else [str(runs) for runs in sets]


def set_errors(study: Study, runs: Path, profile: Path) -> pd.DataFrame:
    """One row per configuration of both halves with a run in `runs`: its replay and
    prediction frame-time errors, with `profile` (columns `half`, `config`, `replay`,
    `prediction`)."""
    frames = []
    speeds: pipeline.SpeedTables = {}  # the set's speed record, read once for both halves
    with tempfile.TemporaryDirectory() as work:
        for title, held in HALVES:
            entries = study.held_out if held else study.calibration
            if not entries:
                continue
            table = pipeline.validate(study, entries, runs, profile, Path(work) / title,
                                      lambda _message: None, figures=False, speed_tables=speeds)
            if len(table):
                frames.append(pd.DataFrame({
                    "half": "held out" if held else "calibration", "config": table["config"],
                    "replay": table["replay_frame_time_error"], "prediction": table["frame_time_error"]}))
    if not frames:
        return pd.DataFrame(columns=ERROR_COLUMNS[1:])
    return pd.concat(frames, ignore_index=True)


def spread(errors: pd.DataFrame) -> pd.DataFrame:
    """Per (half, config) seen in every set: its replay error in each set (columns by set),
    and `half_range` = (max - min) / 2, the floor under any one timeline's worst error on it."""
    table = errors.pivot_table(index=["half", "config"], columns="set", values="replay").dropna()
    table["half_range"] = (table.max(axis=1) - table.min(axis=1)) / 2
    return table.sort_values("half_range")


def floor(spread_table: pd.DataFrame) -> pd.DataFrame:
    """Per set, from :func:`spread`'s table: the replay's median and worst |error|, and those of
    its errors' distance from each configuration's mid-range over the sets (the best one
    timeline per configuration could do), over the configurations seen in every set."""
    table = spread_table.drop(columns="half_range")
    centre = (table.max(axis=1) + table.min(axis=1)) / 2
    best = table.sub(centre, axis=0).abs()
    return pd.DataFrame({"replay_median": table.abs().median(), "replay_worst": table.abs().max(),
                         "floor_median": best.median(), "floor_worst": best.max()})
