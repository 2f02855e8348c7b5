"""How far one configuration's replay error moves between sets of runs of the same study.

    PYTHONPATH=. python experiments/replay_repeatability.py STUDY RUNS RUNS... \
        [--profile P] [--only REGEX] [--out DIR]

Each RUNS is a measured runs folder of STUDY (packed or not): a main job's `runs/`, a study's
committed runs, a repeat set. Every configuration with a run in each set is validated offline
(`mgpusim study validate --held-out --no-figures`, both halves) with `--profile`, or, without it,
with the `profile.toml` beside each RUNS folder (a main job's own profile). Nothing is measured.

Why: the replay gives every task the duration the run measured for it, so its error is the
timeline's, whatever the machine's speed. But the timeline's hand-offs (a thread waking on
another GPU's fence) are not the same from one set of runs to the next where the kernel wakes
threads late on busy cores: one configuration's replay error then moves between sets that the
replay cannot tell apart (the same schedule, the same measured durations' kind). No model that
gives a configuration one timeline can be closer, in every set, than half the range its error
spans over the sets. This prints that floor beside the replay errors themselves.

Prints per configuration the replay error in each set and its half-range; then per set the
median and worst distance of its errors from each configuration's mid-range (the best a model of
one timeline per configuration can do on these sets) against the replay's own median and worst.
`--out DIR` also writes `replay_errors.csv` (set, half, config, replay and prediction error).
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

import pandas as pd

from mgpusim.studies import steps as pipeline
from mgpusim.studies.spec import Study, load_study

HALVES = ((pipeline.CALIBRATION_TITLE, False), (pipeline.HELD_OUT_TITLE, True))


def set_profile(runs: Path, profile: Path | None) -> Path:
    """The profile to replay a set with: the one given, else the set's own beside it."""
    if profile is not None:
        return profile
    own = runs.parent / "profile.toml"
    if not own.is_file():
        raise SystemExit(f"{runs}: no profile.toml beside it; give --profile")
    return own


def label(runs: Path) -> str:
    """A set's name in the tables: a main job's folder for its `runs/`, else the folder."""
    return runs.parent.name if runs.name == "runs" else runs.name


def set_errors(study: Study, runs: Path, profile: Path, only: str | None, work: Path) -> pd.DataFrame:
    """One row per configuration of both halves with a run in `runs`: its replay and
    prediction frame-time errors, with `profile`."""
    pattern = re.compile(only) if only else None
    frames = []
    for title, held in HALVES:
        entries = tuple(e for e in (study.held_out if held else study.calibration)
                        if pattern is None or pattern.search(e.name))
        if not entries:
            continue
        table = pipeline.validate(study, entries, runs, profile, work / title, lambda _m: None,
                                  figures=False)
        if len(table):
            frames.append(pd.DataFrame({
                "half": "held out" if held else "calibration", "config": table["config"],
                "replay": table["replay_frame_time_error"], "prediction": table["frame_time_error"]}))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(
        columns=["half", "config", "replay", "prediction"])


def spread(errors: pd.DataFrame) -> pd.DataFrame:
    """Per (half, config) seen in every set: its replay error in each set (columns by set),
    and `half_range` = (max - min) / 2, the floor under any one timeline's worst error on it."""
    table = errors.pivot_table(index=["half", "config"], columns="set", values="replay")
    table = table.dropna()
    table["half_range"] = (table.max(axis=1) - table.min(axis=1)) / 2
    return table.sort_values("half_range")


def floor(errors: pd.DataFrame) -> pd.DataFrame:
    """Per set: the replay's median and worst |error|, and those of its errors' distance from
    each configuration's mid-range over the sets (the best one timeline per configuration could
    do), over the configurations seen in every set."""
    table = spread(errors).drop(columns="half_range")
    centre = (table.max(axis=1) + table.min(axis=1)) / 2
    best = table.sub(centre, axis=0).abs()
    return pd.DataFrame({"replay_median": table.abs().median(), "replay_worst": table.abs().max(),
                         "floor_median": best.median(), "floor_worst": best.max()})


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("study", type=Path)
    p.add_argument("runs", type=Path, nargs="+", help="two or more measured runs folders")
    p.add_argument("--profile", type=Path, help="one profile for every set (default: each set's own)")
    p.add_argument("--only", help="a regular expression: only the configurations it finds")
    p.add_argument("--out", type=Path, help="folder for replay_errors.csv")
    args = p.parse_args(argv)
    if len(args.runs) < 2:
        p.error("give two or more runs folders")
    study = load_study(args.study)
    names = [label(runs) for runs in args.runs]
    if len(set(names)) < len(names):  # two sets of one name: their paths tell them apart
        names = [str(runs) for runs in args.runs]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (runs, name) in enumerate(zip(args.runs, names)):
            print(f"replaying {runs} ...", file=sys.stderr)
            errors = set_errors(study, runs, set_profile(runs, args.profile), args.only, Path(tmp) / str(i))
            rows.append(errors.assign(set=name))
    errors = pd.concat(rows, ignore_index=True)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        errors.to_csv(args.out / "replay_errors.csv", index=False)
    table = spread(errors)
    if table.empty:
        raise SystemExit("no configuration has a run in every set")
    with pd.option_context("display.width", 200, "display.max_columns", 20, "display.max_rows", 500):
        print((table * 100).round(1).to_string())
        print(f"\n{len(table)} configurations; half-range of the replay error over the sets: "
              f"median {table.half_range.median():.1%}, worst {table.half_range.max():.1%}")
        print("\nper set, |replay error| against the floor of one timeline per configuration (%):")
        print((floor(errors) * 100).round(1).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
