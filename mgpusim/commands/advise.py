"""`mgpusim advise EXPERIMENT [--out DIR]`: the best multi-GPU schedule, GPU count and link
for a frame (usually one from `mgpusim frame import`).

Searches sort-first (balanced tiles), sort-last, AFR (also evenly paced), frame pipelining
(every split point, 1-8 chunks) and XR (a frame with two views) on 1-8 GPUs over PCIe 3/4/5
x8/x16 and NVLink, at the analytic level first, then confirms the best at full fidelity. Ranks
by the 99th-percentile interval between presents; ties (within 1 %) go to the lower latency,
fewer GPUs, the cheaper link (docs/advise.md). Writes DIR/report.html (tables,
the Pareto plot, timelines, Perfetto traces), advice.csv, advice.json and pareto.png.

Progress on stderr while it searches. DIR is held by one mgpusim at a time (a second is
refused); an earlier advice in it is removed first, the new one moved in at the end, the
report last, so a killed run leaves no report rather than an old one beside a new table.
Frames of up to 64 passes (frame pipelining's options grow with them).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mgpusim.io.out_folder import check_out_dir, locked_out_dir
from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError

if TYPE_CHECKING:  # annotations only: loaded when the command runs
    from mgpusim.advise.advisor import Advice


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("advise", help="search schedules, GPU counts and links for a frame; an HTML report",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("experiment", help="experiment TOML file on one GPU (e.g. from `mgpusim frame import`)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: out/<experiment>-advice)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="an override applied to every option, as for `simulate` (e.g. profile.gpus.*.speed=2)")
    p.add_argument("--max-gpus", type=int, default=8, metavar="N", help="GPU counts 1..N (default 8)")
    p.add_argument("--confirm", type=int, default=24, metavar="K",
                   help="options confirmed at full fidelity besides the analytic Pareto front (default 24)")
    p.add_argument("--timelines", type=int, default=3, metavar="N",
                   help="timelines and Perfetto traces of the N best options (default 3)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes evaluating options (default: one per CPU)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.advise.advisor import check_frame  # noqa: PLC0415
    from mgpusim.schedules.experiment import parse_overrides  # noqa: PLC0415
    for name, value, low in (("--confirm", args.confirm, 1), ("--timelines", args.timelines, 0),
                             ("--workers", args.workers, 1)):
        if value is not None and value < low:
            raise InputError(f"must be >= {low}, got {value}", field=name)
    path = resolve_experiment(args.experiment)
    out = args.out or Path("out") / f"{path.stem}-advice"
    check_out_dir(out)
    overrides = parse_overrides(args.overrides)
    check_frame(path, overrides, args.max_gpus)  # bad input leaves the folder as it was
    with locked_out_dir(out):
        return _advise(args, path, overrides, out)


def _advise(args: argparse.Namespace, path: Path, overrides: dict[str, Any], out: Path) -> int:
    """The search, the report and the summary lines, with `out` held by this process. One
    set of worker processes serves every stage; the assumed shares are checked while the
    timelines are drawn (both need only the search); the garbage collector runs less often."""
    import os  # noqa: PLC0415
    import time  # noqa: PLC0415

    from mgpusim.advise.advisor import search  # noqa: PLC0415
    from mgpusim.advise.assumptions import check_shares  # noqa: PLC0415
    from mgpusim.advise.report import discard_stale, write_advice  # noqa: PLC0415
    from mgpusim.advise.worker_set import Workers, fewer_collections  # noqa: PLC0415
    from mgpusim.io.progress import Stages  # noqa: PLC0415
    discard_stale(out)
    t0 = time.perf_counter()
    with (fewer_collections(), Stages("advise", unit="option") as progress,
          Workers(args.workers or os.cpu_count() or 1) as workers):
        advice = search(path, overrides, max_gpus=args.max_gpus, confirm=args.confirm,
                        workers=workers, progress=progress)
        searched = time.perf_counter() - t0
        files = write_advice(advice, out, str(args.experiment), args.timelines, progress, workers,
                             lambda: check_shares(advice, workers, progress=progress))
    _summary(advice, path, out, files, searched + advice.timings.get("shares_s", 0.0))
    return 0


def _summary(advice: Advice, path: Path, out: Path, files: dict[str, Path], searched: float) -> None:
    """What the command prints: the search, the baseline, the best, the front, the notes."""
    from mgpusim.advise.advisor import RANK_MEASURE  # noqa: PLC0415
    rows = advice.ranked.drop_duplicates("rank")
    best, base = rows.iloc[0], advice.baseline
    print(f"{path.stem}: {advice.counts['options']} options in {searched:.1f} s "
          f"({', '.join(f'{k} {v:.1f}' for k, v in advice.timings.items())}; "
          f"{advice.counts['confirmed']} confirmed at full fidelity, {advice.counts['workers']} worker(s))")
    print(f"  ranked by {RANK_MEASURE}")
    print(f"  one GPU: p99 interval {base['interval_p99_ms']:.3f} ms (mean {base['frame_time_ms']:.3f}), "
          f"latency {base['latency_ms']:.3f} ms")
    print(f"  best: {best['label']}: p99 interval {best['interval_p99_ms']:.3f} ms (mean "
          f"{best['frame_time_ms']:.3f}, worst {best['interval_max_ms']:.3f}; {best['speedup']:.2f}x), "
          f"latency {best['latency_ms']:.3f} ms")
    front = rows[rows["pareto"]]
    print(f"  Pareto front (p99 interval against latency): {len(front)} option(s)")
    for _, row in front.head(8).iterrows():
        print(f"    {row['rank_ms']:8.3f} ms  latency {row['latency_ms']:8.3f} ms  {row['label']}"
              + (f" (tied: also {row['also_on']})" if isinstance(row["also_on"], str) and row["also_on"] else ""))
    if advice.analytic_bound and advice.open:
        print(f"  {advice.open} option(s) not confirmed could be faster: raise --confirm")
    for note in advice.notes:
        print(f"  note: {note}")
    print(f"  wrote {files['report']} (and {out / 'advice.csv'}, {out / 'advice.json'}, {out / 'pareto.png'})")
