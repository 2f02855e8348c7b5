"""`mgpusim simulate EXPERIMENT.toml [--set key=value ...] [--out DIR]`."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..experiment import load_experiment, parse_overrides
from ..outpath import check_out_dir
from ..output import write_result
from ..simulate import simulate


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run an experiment in the model and write its results")
    p.add_argument("experiment", type=Path, help="experiment TOML file")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="override a field, e.g. schedule.gpus=3 or scene.width=1920 (repeatable)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: out/<experiment name>)")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="trace table format")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    exp = load_experiment(args.experiment, parse_overrides(args.overrides))
    out = args.out or Path("out") / exp.name
    check_out_dir(out)
    result = simulate(exp)
    files = write_result(result, out, args.format, title=f"{exp.name}: {exp.schedule.name}, "
                         f"{exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}")
    s = result.summary
    print(f"{exp.name}: {exp.schedule.name} on {exp.schedule.gpus} GPU(s) of {exp.profile.name}, "
          f"{exp.scene.width}x{exp.scene.height}")
    print(f"  frame time {s['frame_time_ms']:.3f} ms ({s['fps']:.1f} fps), latency {s['latency_ms']:.3f} ms, "
          f"jitter {s['frame_time_jitter_ms']:.3f} ms")
    for name, hz in s.get("task_rates_hz", {}).items():
        if name != "frames":
            print(f"  {name}: {hz:.1f} Hz (frames {s['fps']:.1f} Hz)")
    busiest = sorted(s.get("utilization", {}).items(), key=lambda kv: -kv[1])[:4]
    print("  busiest: " + ", ".join(f"{k} {v:.0%}" for k, v in busiest))
    print(f"  wrote {', '.join(str(p) for p in files.values())}")
    return 0
