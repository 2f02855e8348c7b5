"""`mgpusim main [--out DIR] [--held-out]`: measure, calibrate and validate on lavapipe."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..calibrate import apply, calibrate, lavapipe_base, read_measurements, report
from ..mainjob import HELD_OUT, MAIN_CONFIGS, measure_all, validate_all, write_report


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="the main job: measure, calibrate, validate on lavapipe, write a report")
    p.add_argument("--out", type=Path, default=Path("out/main"))
    p.add_argument("--held-out", action="store_true",
                   help="also validate 10 held-out configurations (GPU counts, sizes, loads)")
    p.add_argument("--measurements", type=Path, nargs="*",
                   help="re-use these measurement tables instead of measuring")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import tomli_w  # noqa: PLC0415

    t0 = time.monotonic()

    def progress(msg: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    out: Path = args.out
    tables = args.measurements or measure_all(out / "measurements", progress)
    progress("calibrate")
    df, machine = read_measurements(list(tables))
    cal = calibrate(df, machine)
    profile = out / "profile.toml"
    profile.write_text(tomli_w.dumps(apply(cal, lavapipe_base(machine), "mgpusim main")))
    fit_text = report(cal)
    configs = MAIN_CONFIGS + (HELD_OUT if args.held_out else [])
    table = validate_all(configs, profile, out / "validation", progress)
    path = write_report(out, table, fit_text, held_out=True)
    print(path.read_text())
    progress(f"done: {path}")
    return 0
