"""`mgpusim bench [--frames N] [--json]`: model speed against raw SimPy on this machine."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..bench import DEFAULT_EXPERIMENT, run_bench


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="simulated frames per second, and cost per resource use vs raw SimPy")
    p.add_argument("--experiment", type=Path, default=DEFAULT_EXPERIMENT,
                   help="a sort-first experiment with a profile of >= 4 GPUs for the 4-GPU figure")
    p.add_argument("--frames", type=int, default=5000)
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = run_bench(args.experiment, args.frames)
    if args.json:
        print(json.dumps(out, sort_keys=True))
        return 0
    print(f"raw SimPy (request/timeout/release on a Resource): {out['raw_simpy_uses_per_s']:,.0f} uses/s")
    for key in ("sort_first_2gpu", "sort_first_4gpu"):
        fig = out[key]
        if "error" in fig:
            print(f"{key}: skipped ({fig['error']})")
            continue
        print(f"{key}: {fig['frames_per_s']:,.0f} simulated frames/s, {fig['uses_per_s']:,.0f} resource uses/s, "
              f"cost per use {fig['cost_ratio_vs_raw_simpy']:.2f}x raw SimPy")
    return 0
