"""`mgpusim study measure|calibrate|validate|run STUDY.toml`: a study's steps from the command line.

- measure: the microbenchmark sweeps and every configuration's runs, on Vulkan, into OUT;
- calibrate: fit a profile from the tables and the calibration runs (no device needed);
- validate: compare each configuration's measured run with the model (no device needed);
- run: all of it, and report.md (`mgpusim main` runs the lavapipe study this way);
  `validate`, `run` and `mgpusim main` end with the verdict line and one exit status rule
  (:mod:`mgpusim.studies.verdict`: 0 targets met, 1 a target missed or not shown met, 2 bad
  input, 3 nothing could be measured or compared);
- floor: replay several sets of the study's runs and say how far each configuration's replay
  error moves between them (no device needed).
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import re
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, TypeVar

from mgpusim.io.out_folder import check_out_dir, locked_out_dir
from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.model.toml_checks import int_list

T = TypeVar("T")

if TYPE_CHECKING:  # annotations only: loaded when the command runs
    import pandas as pd

    from mgpusim.studies.study_file import Study


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="measure, calibrate and validate a study (a set of configurations)")
    steps = p.add_subparsers(dest="step", required=True, metavar="STEP")
    for name, doc in (("measure", "measure the study's microbenchmarks and runs on Vulkan"),
                      ("calibrate", "fit a profile from the tables and calibration runs"),
                      ("validate", "compare measured runs with the model (no device needed)"),
                      ("run", "measure, calibrate, validate and report")):
        s = steps.add_parser(name, help=doc, description=doc)
        s.add_argument("study", type=Path, help="study TOML file (a shipped one by its checkout path too)")
        s.add_argument("--out", type=Path, default=None, help="output folder (default out/<study name>)")
        if name in ("measure", "run"):
            s.add_argument("--devices", help="physical device of each simulated GPU, e.g. 0,1 (NVIDIA)")
            s.add_argument("--only", help="only the configurations whose name this regular expression "
                           "matches anywhere (a plain substring works; ^sf_ for names that start so)")
            add_steady_check(s)
        if name in ("measure", "run", "validate"):
            s.add_argument("--held-out", action="store_true", help="include the held-out configurations")
        if name in ("calibrate", "validate"):
            s.add_argument("--runs", type=Path, help="measured runs folder (default: the study's "
                           "committed runs, else OUT/runs)")
            s.add_argument("--allow-missing", action="store_true", help="compare the configurations "
                           "that have runs and list the rest first in the report (default: a half "
                           "without every run is refused)")
        if name == "validate":
            s.add_argument("--no-figures", dest="figures", action="store_false",
                           help="tables only: no timelines or Perfetto traces per configuration (5x faster)")
            s.add_argument("--profile", type=Path, help="profile to simulate with (default: the study's)")
            s.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                           help="an override added to every configuration (repeatable)")
        s.set_defaults(func=_STEPS[name])
    doc = ("replay several sets of the study's runs: how far each configuration's replay error "
           "moves between them, the floor under any model's (no device needed)")
    f = steps.add_parser("floor", help=doc, description=doc)
    f.add_argument("study", type=Path, help="study TOML file (a shipped one by its checkout path too)")
    f.add_argument("--runs", type=Path, action="append", required=True, metavar="FOLDER",
                   help="a measured runs folder of the study (give two or more)")
    f.add_argument("--profile", type=Path, help="one profile for every set (default: the "
                   "profile.toml beside each runs folder, as a main job writes it)")
    f.add_argument("--only", help="only the configurations whose name this regular expression matches")
    f.add_argument("--out", type=Path, default=None, help="output folder (default out/<study name>-floor)")
    f.set_defaults(func=_held(floor))


def add_steady_check(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steady-check", type=float, default=None, metavar="FRACTION",
                   help="first measure the machine's speed probe a few times (about 30 s) and stop "
                        "if it moved more than FRACTION (e.g. 0.1); lavapipe studies only")
    p.add_argument("--wait-steady", type=float, default=None, metavar="MINUTES",
                   help="with --steady-check: instead of stopping, check again every minute until "
                        "the machine is steady, for up to MINUTES")


def steady_check(args: argparse.Namespace, study: Study, out: Path,
                 progress: Callable[[str], None]) -> None:
    """With --steady-check: the probes before any other work (with --wait-steady, tried until
    they agree); on a steady machine they open the job's probe table (out/measurements), on a
    drifting one nothing is written."""
    from mgpusim.measure import speed_probe as speed  # noqa: PLC0415
    if args.steady_check is None:
        if args.wait_steady is not None:
            raise InputError("--wait-steady waits for --steady-check to pass; give both",
                             field="--wait-steady")
        return
    if args.wait_steady is None:
        rows = speed.check_steady(study.lavapipe_threads(), args.steady_check, progress)
    else:
        rows = speed.wait_steady(study.lavapipe_threads(), args.steady_check, args.wait_steady,
                                 progress)
    (out / "measurements").mkdir(parents=True, exist_ok=True)
    speed.append_probe(out / "measurements" / speed.FILE, rows)


def progress_printer() -> Callable[[str], None]:
    """Progress lines on stderr, stamped with seconds since the command started."""
    t0 = time.monotonic()

    def progress(msg: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)
    return progress


def measuring(step: Callable[[], T]) -> T | int:
    """`step()` (measuring on the device), or the exit status 3 with one `could not measure:`
    line where it could not: an error that is not bad input (no Vulkan driver or device, a
    Vulkan call failing, `--steady-check` finding the machine moving). Bad input stays an
    InputError (exit 2)."""
    from mgpusim.studies.verdict import NOT_MEASURED  # noqa: PLC0415
    try:
        return step()
    except InputError:
        raise
    except MgpusimError as exc:
        print(f"could not measure: {' '.join(str(exc).split())}", file=sys.stderr)  # one line
        return NOT_MEASURED


def finish(out: Path) -> int:
    """The verdict line (stdout, last) and the exit status of a report written into `out`."""
    from mgpusim.io.table_files import read_json_object  # noqa: PLC0415
    from mgpusim.studies import verdict  # noqa: PLC0415
    stats = read_json_object(out / "errors.json")
    print(verdict.verdict_line(stats))
    return verdict.exit_status(stats)


def _out(args: argparse.Namespace, study: Study) -> Path:
    """The output folder, checked and held (:func:`_hold`) before any work."""
    out = args.out or Path("out") / study.name
    return _hold(args, out)


def _held(step: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """`step` with the output folder it names through :func:`_hold` locked until it returns."""
    @functools.wraps(step)
    def run(args: argparse.Namespace) -> int:
        with contextlib.ExitStack() as args.held:
            return step(args)
    return run


def _hold(args: argparse.Namespace, out: Path) -> Path:
    """`out` checked and, for the rest of the step (:func:`_held`), held by this process: a
    second mgpusim writing it meanwhile is refused, not left to mix its files with ours."""
    held = getattr(args, "held", None)
    if held is None:  # a step called directly, not through the command line
        check_out_dir(out)
        return out
    held.enter_context(locked_out_dir(out))
    return out


def _filtered(study: Study, args: argparse.Namespace) -> Study:
    if not getattr(args, "only", None):
        return study
    try:
        pattern = re.compile(args.only)
    except re.error as e:
        raise InputError(f"--only {args.only!r} is not a regular expression: {e}") from None
    keep = lambda es: tuple(e for e in es if pattern.search(e.name))  # noqa: E731
    kept = replace(study, calibration=keep(study.calibration), held_out=keep(study.held_out))
    if not kept.calibration and not kept.held_out:
        raise InputError(f"--only {args.only!r} matches no configuration of {study.name}")
    return kept


def measure(args: argparse.Namespace) -> int:
    from mgpusim.studies.measuring import measure_microbenchmarks, measure_runs  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    study = _filtered(load_study(resolve_experiment(args.study)), args)
    out, progress = _out(args, study), progress_printer()
    steady_check(args, study, out, progress)
    if study.microbenchmarks.sweeps and study.microbenchmarks.folder is None:
        measure_microbenchmarks(study, out / "measurements", progress)
    measure_runs(study, study.entries(args.held_out), study.profile, out / "runs", progress,
                 int_list(args.devices, "--devices"))
    print(f"wrote {out}")
    return 0


def calibrate(args: argparse.Namespace) -> int:
    from mgpusim.studies import pipeline as pipeline  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    study = load_study(resolve_experiment(args.study))
    out = _out(args, study)
    profile, text = pipeline.calibrate(study, out, progress_printer(), runs_dir=args.runs,
                                       allow_missing=args.allow_missing)
    print(text)
    print(f"wrote {profile}")
    return 0


def validate(args: argparse.Namespace) -> int:
    import pandas as pd  # noqa: PLC0415

    from mgpusim.studies import pipeline as pipeline  # noqa: PLC0415
    from mgpusim.studies import run_sets  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    from mgpusim.vmgpu import frame_times  # noqa: PLC0415
    if frame_times.is_frame_time_study(resolve_experiment(args.study)):
        return validate_frame_times(args)
    study = load_study(resolve_experiment(args.study))
    out, progress = _out(args, study), progress_printer()
    profile = args.profile or study.profile
    tables, missing = {}, {}
    speeds: pipeline.SpeedTables = {}  # each runs folder's run_speed.csv, read once for both halves
    calibration_root = args.runs or pipeline.runs_root(study, False, out)
    halves = [(pipeline.CALIBRATION_TITLE, study.calibration, False),
              (pipeline.HELD_OUT_TITLE, study.held_out, True)][:2 if args.held_out else 1]
    for title, entries, held in halves:  # every half checked before any is compared
        root = args.runs or pipeline.runs_root(study, held, out)
        missing[title] = list(run_sets.check_half(study, entries, root, "--runs" if args.runs else "",
                                                  args.allow_missing, title.split()[0].lower()).missing)
    for title, entries, held in halves:
        root = args.runs or pipeline.runs_root(study, held, out)
        tables[title] = pipeline.validate(study, entries, root, profile, out / "validation",
                                          progress, tuple(args.extra), args.figures, calibration_root,
                                          speeds)
    path = pipeline.write_report(out, study, tables, f"profile: {profile}",  # also errors.json
                                 pipeline.probes_of(calibration_root), missing,
                                 pipeline.speed_table(speeds, calibration_root))
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        for title, table in tables.items():
            print(f"{title}\n{table.to_string(index=False)}")
            if missing[title]:
                print(f"no measured run (not compared): {', '.join(missing[title])}")
    print((out / "errors.json").read_text())
    print(f"wrote {path}")
    return finish(out)


def validate_frame_times(args: argparse.Namespace) -> int:
    """`study validate` of a frame-time study (an external renderer's measured frame times):
    its one parameter fitted on the calibration half, then each half compared (no replay:
    such a renderer writes no per-task timestamps)."""
    from mgpusim.io.writers import write_text  # noqa: PLC0415
    from mgpusim.vmgpu import frame_times  # noqa: PLC0415
    for flag in ("runs", "profile"):
        if getattr(args, flag, None) is not None:
            raise InputError(f"--{flag} is for studies of our own runner's runs; a frame-time study "
                             f"names its table and profile in its file", field=f"--{flag}")
    if args.extra:
        raise InputError("--set is for studies of our own runner's runs", field="--set")
    study = frame_times.load_study(resolve_experiment(args.study))
    out, progress = args.out or Path("out") / study.name, progress_printer()
    _hold(args, out)
    result = frame_times.validate(study, args.held_out, progress)
    page = frame_times.markdown(result)
    out.mkdir(parents=True, exist_ok=True)
    for half, table in result.halves.items():
        table.to_csv(out / f"{half}.csv", index=False)
    write_text(page, out / "report.md")
    print(page)
    print(f"wrote {out}")
    return 0 if result.met else 1  # the exit rule of every study command (README)


def run(args: argparse.Namespace) -> int:
    from mgpusim.studies import pipeline as pipeline  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    study = _filtered(load_study(resolve_experiment(args.study)), args)
    out, progress = _out(args, study), progress_printer()
    devices = int_list(args.devices, "--devices")

    def job() -> Path:
        steady_check(args, study, out, progress)
        return pipeline.run(study, out, progress, args.held_out, devices)
    path = measuring(job)
    if isinstance(path, int):
        return path
    print(path.read_text())
    return finish(out)


def floor(args: argparse.Namespace) -> int:
    import pandas as pd  # noqa: PLC0415

    from mgpusim.studies import floor as replay_floor  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    if len(args.runs) < 2:
        raise InputError("give two or more --runs folders", field="--runs")
    missing = [str(runs) for runs in args.runs if not runs.is_dir()]
    if missing:
        raise InputError(f"no such runs folder: {', '.join(missing)}", field="--runs")
    whole = load_study(resolve_experiment(args.study))
    replay_floor.check_sets(whole, args.runs)  # the study's own runs, each set measured apart
    study = _filtered(whole, args)
    out = args.out or Path("out") / f"{study.name}-floor"
    _hold(args, out)
    profiles = [replay_floor.set_profile(runs, args.profile) for runs in args.runs]  # all checked first
    rows = []
    for runs, name, profile in zip(args.runs, replay_floor.set_names(args.runs), profiles):
        print(f"replaying {runs} with {profile} ...", file=sys.stderr)
        rows.append(replay_floor.set_errors(study, runs, profile).assign(set=name))
    errors = pd.concat(rows, ignore_index=True)[replay_floor.ERROR_COLUMNS]
    table = replay_floor.spread(errors)
    if table.empty:
        raise InputError("no configuration has a run in every set", field="--runs")
    per_set = replay_floor.floor(table)
    out.mkdir(parents=True, exist_ok=True)
    errors.to_csv(out / "replay_errors.csv", index=False)
    table.to_csv(out / "replay_floor.csv")
    per_set.to_csv(out / "replay_floor_per_set.csv")
    _print_floor(table, per_set)
    print(f"wrote {out}")
    return 0


def _print_floor(table: pd.DataFrame, per_set: pd.DataFrame) -> None:
    """The floor's two tables, in percent."""
    import pandas as pd  # noqa: PLC0415
    with pd.option_context("display.width", 200, "display.max_columns", 20, "display.max_rows", 1000):
        print((table * 100).round(1).to_string())
        print(f"\n{len(table)} configurations; half-range of the replay error over the sets: "
              f"median {table.half_range.median():.1%}, worst {table.half_range.max():.1%}")
        print("\nper set, |replay error| against the floor of one timeline per configuration (%):")
        print((per_set * 100).round(1).to_string())


_STEPS = {name: _held(step) for name, step in
          {"measure": measure, "calibrate": calibrate, "validate": validate, "run": run}.items()}
