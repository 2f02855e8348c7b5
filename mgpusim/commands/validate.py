"""`mgpusim validate EXPERIMENT.toml --profile PROFILE.toml [--set ...] [--out DIR] [--measured DIR]`.

Runs the experiment's schedule for real (or re-uses a saved measured run) and in the model,
and reports measured against simulated frame time, latency and every step's mean duration.
Measuring is robust by default on a noisy machine: several runs, each long enough to average
the machine's phases, compared over their steady window, with the runs' spread reported.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mgpusim.io.out_folder import check_out_dir
from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="run a schedule for real and in the model, report the errors")
    p.add_argument("experiment", type=Path, help="experiment TOML file, or a shipped name (`mgpusim examples`)")
    p.add_argument("--profile", type=Path, help="calibrated profile to simulate with (default: the experiment's)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="override a field of the experiment, as simulate takes it (repeatable)")
    p.add_argument("--measured", type=Path, help="a saved measured run (from `mgpusim run` or an "
                   "earlier validate's measured/ folder): no device needed")
    p.add_argument("--out", type=Path, help="output folder (default out/<name>-validate)")
    p.add_argument("--repeats", type=int, default=3,
                   help="measured runs (default 3); their steady window is compared")
    p.add_argument("--run-seconds", type=float, default=1.0,
                   help="timed length of each measured run, frames added to reach it (default 1.0; "
                        "with --repeats 1 and 0 the experiment's own frames are compared whole)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.schedules.experiment import load_experiment, parse_overrides  # noqa: PLC0415
    from mgpusim.validation.crossvalidate import format_report, validate_experiment  # noqa: PLC0415
    exp = load_experiment(resolve_experiment(args.experiment), parse_overrides(args.overrides),
                          profile=args.profile)
    out = args.out or Path("out") / f"{exp.name}-validate"
    if args.repeats < 1 or not args.run_seconds >= 0:
        raise InputError(f"need --repeats >= 1 and --run-seconds >= 0, got {args.repeats} and "
                         f"{args.run_seconds}")
    check_out_dir(out)
    report = validate_experiment(exp, out, args.measured, args.repeats, args.run_seconds)
    print(format_report(exp, report))
    print(f"  wrote {out}")
    return 0
