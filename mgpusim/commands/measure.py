"""`mgpusim measure`: time a pass of the Vulkan pass library over a parameter sweep.

Writes a tidy table (CSV or Parquet by extension: device, gpu, gpus, lp_threads, pass, one
column per parameter, repetition, duration_ns, cpu_ns, bytes) and FILE.machine.json (CPU, driver,
threads, library versions).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from mgpusim.io.out_folder import check_out_file
from mgpusim.model.errors import InputError
from mgpusim.model.toml_checks import int_list


def _list() -> int:
    from mgpusim.measure.microbench import PASSES  # noqa: PLC0415 - keeps `--help` free of numpy/pandas

    for spec in PASSES.values():
        params = ", ".join(f"{k}={v}" for k, v in spec.params.items())
        print(f"{spec.name:22s} {params}\n{'':22s} {spec.doc}")
    return 0


def _overlap_table(df) -> str:
    """Each pair's efficiency from the fastest of its repetitions, per measured size."""
    from mgpusim.calibration.overlap_fit import fastest_of  # noqa: PLC0415

    lines = ["pair                queues                          alone A / B (ms)   together (ms)"
             "  efficiency  note"]
    r: Any  # a row's fields (pandas-stubs types each as any scalar)
    for r in fastest_of(df).itertuples(index=False):
        lines.append(f"{r.pair:19s} {r.queue_a + ' + ' + r.queue_b:31s} {r.alone_a_ns / 1e6:7.3f} / "
                     f"{r.alone_b_ns / 1e6:7.3f} {r.duration_ns / 1e6:13.3f}  {r.efficiency:10.3f}  "
                     f"{r.missing or ''}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from mgpusim.io.writers import write_json  # noqa: PLC0415
    if args.list:
        return _list()
    if not args.pass_name or not args.out:
        raise InputError("need --pass NAME and --out FILE (or --list)")
    if not args.out.lower().endswith((".csv", ".parquet", ".pq")):
        raise InputError(f"expected a .csv or .parquet file, got {args.out!r}", field="--out")
    check_out_file(Path(args.out))
    for name in ("reps", "gpus"):
        if getattr(args, name) < 1:
            raise InputError(f"must be >= 1, got {getattr(args, name)}", field=f"--{name}")
    if args.warmup < 0:
        raise InputError(f"must be >= 0, got {args.warmup}", field="--warmup")
    from tqdm import tqdm  # noqa: PLC0415

    from mgpusim.measure import microbench as m  # noqa: PLC0415
    from mgpusim.real.vulkan.machine import close_gpus, machine_record, make_gpus  # noqa: PLC0415

    sweeps = m.parse_sweeps(args.pass_name, args.sweep or [])
    combos = len(m.combinations(args.pass_name, sweeps))
    lp = int_list(args.lp_threads, "--lp-threads")
    count, device = args.gpus, args.device
    if args.pass_name == "overlap":  # its pairs' VkDevices, all on one physical GPU
        from mgpusim.measure.overlap import gpus_needed  # noqa: PLC0415
        count, device = gpus_needed(sweeps.get("pair", [m.PASSES["overlap"].params["pair"]])), device or 0
    gpus = [] if m.spec(args.pass_name).host else make_gpus(count, lp_threads=lp, physical=device)
    try:
        with tqdm(total=combos, desc=args.pass_name, unit="point", file=sys.stderr,
                  disable=args.quiet) as bar:
            df = m.measure(args.pass_name, gpus, sweeps, reps=args.reps, warmup=args.warmup,
                           progress=bar.update)
        m.write_table(df, args.out)
        record = machine_record(gpus, {"command": sys.argv, "pass": args.pass_name,
                                       "sweeps": sweeps, "reps": args.reps,
                                       "warmup": args.warmup})
    finally:
        close_gpus(gpus)
    write_json(record, Path(args.out + ".machine.json"))
    if not args.quiet:
        if args.pass_name == "overlap":
            print(_overlap_table(df))
        print(f"wrote {len(df)} rows to {args.out} (+ .machine.json)")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("measure", help="time Vulkan passes over parameter sweeps",
                              description=__doc__)
    p.add_argument("--list", action="store_true", help="list the passes and their parameters")
    p.add_argument("--pass", dest="pass_name", metavar="NAME", help="pass to measure")
    p.add_argument("--sweep", action="append", metavar="PARAM=V1,V2,...",
                   help="values of one parameter (repeatable; the product is measured)")
    p.add_argument("--reps", type=int, default=5, help="measured repetitions (default 5)")
    p.add_argument("--warmup", type=int, default=2, help="discarded warm-up runs (default 2)")
    p.add_argument("--gpus", type=int, default=1, help="simulated GPUs run at once (default 1)")
    p.add_argument("--lp-threads", metavar="N[,N...]",
                   help="lavapipe LP_NUM_THREADS per simulated GPU (one value: all)")
    p.add_argument("--device", type=int, help="physical device index for every simulated GPU")
    p.add_argument("--out", metavar="FILE", help="output .csv or .parquet")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
