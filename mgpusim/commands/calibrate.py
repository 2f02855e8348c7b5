"""`mgpusim calibrate MEASUREMENTS... --out PROFILE.toml [--base PROFILE.toml]`."""
from __future__ import annotations

import argparse
import copy
import shlex
import sys
from pathlib import Path

from mgpusim.io.out_folder import check_out_file
from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_GPUS
from mgpusim.model.toml_checks import read_toml


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="fit profile coefficients to measurement tables")
    p.add_argument("measurements", nargs="+", type=Path, help="tables from `mgpusim measure` (CSV/Parquet)")
    p.add_argument("--out", type=Path, required=True, help="profile TOML to write")
    p.add_argument("--base", type=Path, help="profile whose structure to keep (default: a lavapipe "
                   "machine made from the measurements' machine record)")
    p.add_argument("--gpus", type=int, default=4, help="simulated GPUs in a lavapipe profile (default 4)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import tomli_w  # noqa: PLC0415

    from mgpusim.calibration import apply, calibrate, lavapipe_base, read_measurements, report  # noqa: PLC0415
    from mgpusim.calibration.profile_out import fit_details  # noqa: PLC0415
    from mgpusim.io.writers import write_json  # noqa: PLC0415
    check_out_file(args.out)
    if not 1 <= args.gpus <= MAX_GPUS:
        raise InputError(f"must be in 1..{MAX_GPUS}, got {args.gpus}", field="--gpus")
    base = _read_base(args.base) if args.base else None
    df, machine = read_measurements(args.measurements)
    cal = calibrate(df, machine)
    base = base or lavapipe_base(machine, args.gpus)
    command = "mgpusim calibrate " + " ".join(shlex.quote(str(p)) for p in args.measurements)
    profile = apply(cal, base, command)
    text = report(cal)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    header = "# Fitted by mgpusim calibrate. Fit report:\n" + "".join(f"#   {line}\n" for line in text.splitlines())
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(header + "\n" + tomli_w.dumps(profile))
    tmp.replace(args.out)
    write_json(fit_details(cal), args.out.with_suffix(".fit.json"))
    print(text)
    print(f"wrote {args.out} and {args.out.with_suffix('.fit.json')}", file=sys.stderr)
    return 0


def _read_base(path: Path) -> dict:
    """The --base profile, validated first so that a bad one names its own file."""
    from mgpusim.model.profile import parse_profile  # noqa: PLC0415
    base = read_toml(path)
    parse_profile(copy.deepcopy(base), str(path))
    return base
