"""`mgpusim sweep EXPERIMENT --grid KEY=V1,V2,... [--grid ...] --out DIR`: the product of the grid.

Writes DIR/sweep.parquet (one row per point: its keys, every summary field, an error column),
DIR/sweep.png and DIR/sweep.json; finished points are kept in DIR/points/ (a file per batch),
so the same command run again after an interruption (even SIGKILL) only runs the points still
missing (at most the last batch's, or about half a second's of points run one by one).

With --fidelity analytic every grid runs as numpy lanes: keys that change only pass costs
(profile.gpus.<i|*>.speed, profile.gpus.<i|*>.costs.<kind>.fixed_ns / .ns_per_<term>) as
lanes of one model, thousands of points at once, and every other key (scene, schedule, other
profile keys) as groups, each built once and run beside the others of its structure; schedules
lanes cannot express (skippable tasks, vsync, over 1,000 frames) run point by point.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mgpusim.io.shipped import resolve_experiment


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="run an experiment over a grid of overrides into one Parquet table",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("experiment", help="experiment TOML file, or a shipped name (`mgpusim examples`)")
    p.add_argument("--grid", action="append", metavar="KEY=V1,V2,...", required=True,
                   help="a key and its values, e.g. schedule.gpus=1,2,3 (repeatable: the points are "
                        "the product of all grids)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="an override applied to every point, as for `simulate` (repeatable)")
    p.add_argument("--fidelity", default="full", metavar="NAME",
                   help="model fidelity passed to the simulator (default: full)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local processes running points (default: one per CPU; 1 runs in this process)")
    p.add_argument("--dask", metavar="ADDRESS", default=None,
                   help="run the points on this Dask scheduler (e.g. tcp://host:8786) instead of locally")
    p.add_argument("--metric", default="frame_time_ms", metavar="FIELD",
                   help="the summary field the plot shows (default: frame_time_ms)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output folder, also the resume state (default: out/<experiment>-sweep)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.sweeps.grid import parse_grid  # noqa: PLC0415, F401 - the sweep's modules, then
    from mgpusim.sweeps.plotter import ahead  # noqa: PLC0415

    with ahead():  # the plot's process, forked before matplotlib is imported (see plotter's doc)
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from mgpusim.schedules.experiment import parse_overrides  # noqa: PLC0415
    from mgpusim.sweeps.grid import parse_grid, sweep  # noqa: PLC0415
    path = resolve_experiment(args.experiment)
    grid = parse_grid(args.grid)
    out = args.out or Path("out") / f"{path.stem}-sweep"
    df = sweep(path, grid, out, overrides=parse_overrides(args.overrides), fidelity=args.fidelity,
               workers=args.workers, dask=args.dask, progress=not args.no_progress, metric=args.metric)
    failed = df[df["error"].notna()]
    print(f"{path.stem}: {len(df)} points over {', '.join(grid)}; {len(failed)} failed")
    ok = df[df["error"].isna()]
    if args.metric in ok and ok[args.metric].notna().any():
        best = ok.loc[ok[args.metric].idxmin()]
        print(f"  lowest {args.metric}: {best[args.metric]:.4g} at "
              + ", ".join(f"{k}={best[k]}" for k in grid))
    for _, row in failed.head(5).iterrows():
        print("  failed " + ", ".join(f"{k}={row[k]}" for k in grid) + f": {row['error']}")
    if "settled" in ok:
        short = ok[~ok["settled"].astype(bool)]
        if len(short):
            print(f"  note: {len(short)} of {len(ok)} points had not settled by the end of their run "
                  f"(column `settled`; why in `settling.note`), e.g. "
                  + ", ".join(f"{k}={short.iloc[0][k]}" for k in grid)
                  + f": {short.iloc[0]['settling.note']}")
    warned = [c for c in ok.columns if c.startswith("warnings.")]
    if warned:
        rows = ok[ok[warned].notna().any(axis=1)]
        print(f"mgpusim sweep: warning: {len(rows)} of {len(ok)} points depend on a value outside every "
              f"shipped profile's (columns warnings.*), e.g. {rows.iloc[0][warned[0]]}", file=sys.stderr)
    print(f"  wrote {out / 'sweep.parquet'}, {out / 'sweep.png'}, {out / 'sweep.json'}")
    if len(failed) == len(df):
        print(f"mgpusim sweep: error: every point failed (the first: {failed['error'].iloc[0]})",
              file=sys.stderr)
        return 1
    return 0
