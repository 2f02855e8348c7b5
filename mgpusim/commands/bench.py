"""`mgpusim bench [--frames N] [--json]`: model speed against raw SimPy on this machine."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..bench import DEFAULT_EXPERIMENT, run_bench
from ..errors import InputError
from ..shipped import resolve_experiment


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="simulated frames per second, and cost per resource use vs raw SimPy")
    p.add_argument("--experiment", type=Path, default=DEFAULT_EXPERIMENT,
                   help="a sort-first experiment file or shipped name (its profile's last GPU is repeated "
                        "if it has fewer than 4)")
    p.add_argument("--frames", type=int, default=5000, help="simulated frames per timed run (default: 5000)")
    p.add_argument("--repeats", type=int, default=3, help="best of this many interleaved runs")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.frames < 2 or args.repeats < 1:
        raise InputError(f"need --frames >= 2 and --repeats >= 1, got {args.frames} and {args.repeats}")
    out = run_bench(resolve_experiment(args.experiment), args.frames, args.repeats)
    if args.json:
        print(json.dumps(out, sort_keys=True))
        return 0
    print(f"raw SimPy (request/timeout/release on a Resource): {out['raw_simpy_uses_per_s']:,.0f} uses/s")
    for key in ("sort_first_2gpu", "sort_first_4gpu"):
        fig = out[key]
        print(f"{key}: {fig['frames_per_s']:,.0f} simulated frames/s, {fig['uses_per_s']:,.0f} resource uses/s "
              f"({fig['uses_per_frame']} per frame: {fig['task_uses_per_frame']} on queues/threads, "
              f"{fig['link_uses_per_frame']} on links)")
        print(f"  cost per resource use {fig['cost_ratio_vs_raw_simpy']:.2f}x raw SimPy "
              f"(per task, copies counted once: {fig['cost_ratio_per_task_vs_raw_simpy']:.2f}x)")
    return 0
