"""`mgpusim main [--out DIR] [--held-out] [--repeats R] [--run-seconds S] [--steady-check F]`:
the lavapipe study (measure, calibrate, validate, report), the README's main command. It ends
with the verdict line and exits as `mgpusim study run` does (:mod:`mgpusim.studies.verdict`):
0 every target met, 1 a target missed or not shown met (the prediction's band too wide), 2 bad
input, 3 nothing could be measured."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from mgpusim.commands.study import add_steady_check, finish, measuring, progress_printer, steady_check
from mgpusim.io.out_folder import locked_out_dir
from mgpusim.io.shipped import shipped_dir

#: The lavapipe study, shipped beside the package's experiments.
LAVAPIPE_STUDY = shipped_dir("experiments") / "lavapipe" / "study.toml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="the main job: the lavapipe study (measure, calibrate, validate, report)")
    p.add_argument("--out", type=Path, default=Path("out/main"), help="output folder (default out/main)")
    p.add_argument("--held-out", action="store_true",
                   help="also validate the held-out configurations (GPU counts, sizes, loads, variants)")
    p.add_argument("--repeats", type=int, default=None,
                   help="measured runs per configuration (their steady window is compared; default: the study's)")
    p.add_argument("--run-seconds", type=float, default=None,
                   help="timed length of each measured run (frames are added to reach it; default: the study's)")
    p.add_argument("--study", type=Path, default=LAVAPIPE_STUDY, help="study file (default: the lavapipe study)")
    add_steady_check(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with locked_out_dir(args.out):  # a second main job into the folder is refused
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from mgpusim.measure import speed_probe as speed  # noqa: PLC0415
    from mgpusim.studies import pipeline as pipeline  # noqa: PLC0415
    from mgpusim.studies.study_file import load_study  # noqa: PLC0415
    study = load_study(args.study)
    runs = study.runs
    if args.repeats is not None:
        runs = replace(runs, repeats=args.repeats)
    if args.run_seconds is not None:
        runs = replace(runs, run_seconds=args.run_seconds)
    progress = progress_printer()

    def job() -> Path:
        steady_check(args, study, args.out, progress)
        return pipeline.run(replace(study, runs=runs), args.out, progress, args.held_out)
    path = measuring(job)
    if isinstance(path, int):
        return path
    print(path.read_text())
    warning = speed.drift_warning(pipeline.probes_of(args.out / "runs"))
    if warning is not None:
        print(f"warning: {warning}: the raw errors include it, the speed-normalized ones scale "
              f"it out and the prediction's band shows what is left; see the report's first "
              f"sections", file=sys.stderr)
    return finish(args.out)
