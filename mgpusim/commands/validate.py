"""`mgpusim validate EXPERIMENT.toml --profile PROFILE.toml [--set ...] [--out DIR] [--measured DIR]`.

Runs the experiment's schedule for real (or re-uses a saved measured run) and in the model,
and reports measured against simulated frame time, latency and every step's mean duration.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pandas as pd

from ..errors import InputError
from ..experiment import Experiment, load_experiment, parse_overrides
from ..measured_check import check_recorded_config, check_trace, read_json_object, read_table
from ..outpath import check_out_dir
from ..output import write_json, write_measured, write_table
from ..perfetto import chrome_trace
from ..plot import comparison_png
from ..simulate import simulate
from ..validate import compare


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="run a schedule for real and in the model, report the errors")
    p.add_argument("experiment", type=Path)
    p.add_argument("--profile", type=Path, help="calibrated profile to simulate with (default: the experiment's)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE")
    p.add_argument("--measured", type=Path, help="a saved measured run (from `mgpusim run` or an "
                   "earlier validate's measured/ folder): no device needed")
    p.add_argument("--out", type=Path, help="output folder (default out/<name>-validate)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    exp = load_experiment(args.experiment, parse_overrides(args.overrides), profile=args.profile)
    out = args.out or Path("out") / f"{exp.name}-validate"
    check_out_dir(out)
    report = validate_experiment(exp, out, args.measured)
    print(format_report(exp, report))
    print(f"  wrote {out}")
    return 0


def validate_experiment(exp: Experiment, out: Path, measured_dir: Path | None = None) -> dict[str, Any]:
    """Measure (or load) and simulate `exp`; write the comparison to `out`; return its summary."""
    if measured_dir is not None:
        measured = read_measured(measured_dir, exp)
    else:
        measured = _measure(exp, out / "measured")
    sim = simulate(exp)
    report = compare(measured, sim.trace, exp.schedule.warmup_frames)
    report["config"] = {"experiment": exp.name, "schedule": exp.schedule.name, "gpus": exp.schedule.gpus,
                        "width": exp.scene.width, "height": exp.scene.height, "profile": exp.profile.name,
                        "overrides_from": exp.file}
    out.mkdir(parents=True, exist_ok=True)
    write_json(report, out / "summary.json")
    write_table(sim.trace, out / "simulated_trace.parquet")
    title = f"{exp.schedule.name}, {exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}"
    comparison_png(measured, sim.trace, out / "timelines.png", title, sim_links=sim.links)
    write_json(chrome_trace(measured, None, f"measured {title}"), out / "measured.perfetto.json")
    write_json(chrome_trace(sim.trace, sim.links, f"simulated {title}"), out / "simulated.perfetto.json")
    return report


def _measure(exp: Experiment, out: Path) -> pd.DataFrame:
    from ..runner.run import run_experiment  # noqa: PLC0415 - needs Vulkan only here
    result = run_experiment(exp)
    write_measured(result, out)
    return result.trace


def read_measured(folder: Path, exp: Experiment) -> pd.DataFrame:
    """A saved measured trace, checked (columns, integer times, end >= start); its recorded
    configuration must match the experiment's."""
    if not folder.is_dir():
        raise InputError("not a folder (expected a measured run from `mgpusim run`)", file=str(folder))
    for name in ("trace.parquet", "trace.csv"):
        path = folder / name
        if path.is_file():
            trace = check_trace(read_table(path), str(path))
            break
    else:
        raise InputError("no trace.parquet or trace.csv in the measured folder", file=str(folder))
    summary = folder / "summary.json"
    if summary.is_file():
        config = read_json_object(summary).get("config", {})
        if not isinstance(config, dict):
            raise InputError("expected an object", file=str(summary), field="config")
        check_recorded_config(config, exp, str(summary))
    return trace


def format_report(exp: Experiment, r: dict[str, Any]) -> str:
    m, s = r["measured"], r["simulated"]
    lines = [f"{exp.name}: {exp.schedule.name}, {exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}",
             f"  {'':12} {'measured':>10} {'simulated':>10} {'error':>8}",
             f"  {'frame (ms)':12} {m['frame_time_ms']:10.3f} {s['frame_time_ms']:10.3f} {r['frame_time_error']:+8.1%}",
             f"  {'latency (ms)':12} {m['latency_ms']:10.3f} {s['latency_ms']:10.3f} {r['latency_error']:+8.1%}"]
    for step, v in r["steps"].items():
        lines.append(f"  {step:12} {v['measured_ms']:10.3f} {v['simulated_ms']:10.3f} {v['error']:+8.1%}")
    return "\n".join(lines)
