"""The main job on lavapipe: measure, calibrate, validate, report.

1. measure the pass library and copies one simulated GPU at a time (`mgpusim measure` sweeps);
2. calibrate a profile of this machine from those tables (`mgpusim calibrate`);
3. run 2-GPU sort-first and sort-last for real and in the model (`mgpusim validate`), and, with
   `held_out=True`, further configurations that the calibration never saw (other GPU counts,
   resolutions, iteration and triangle counts);
4. write report.md with the error table, the fit, the timelines and the Perfetto traces.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from .experiment import load_experiment
from .validate import error_stats, error_table

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments" / "lavapipe"

#: (pass, sweeps): sizes that bracket the validation runs, one GPU at a time.
SWEEPS: list[tuple[str, dict[str, list[Any]]]] = [
    ("fragment_loop", {"width": [128, 256], "height": [96, 192], "iterations": [250, 1000, 4000]}),
    ("mesh", {"width": [128, 256], "height": [96, 192], "triangles": [2000, 10000, 40000]}),
    ("composite_sort_first", {"width": [128, 256], "height": [96, 192], "inputs": [1, 3]}),
    ("composite_sort_last", {"width": [128, 256], "height": [96, 192], "inputs": [1, 3]}),
    ("copy_d2h", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("copy_h2d", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("copy_d2d", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("host_copy", {"bytes": [65536, 262144, 1048576, 4194304], "threads": [1, 2]}),
]


@dataclass(frozen=True)
class Config:
    name: str
    experiment: str
    overrides: dict[str, Any]


MAIN_CONFIGS = [
    Config("sort_first_2gpu", "sort_first.toml", {}),
    Config("sort_last_2gpu", "sort_last.toml", {}),
]
HELD_OUT = [
    Config("sf_1gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 1}),
    Config("sf_3gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 3}),
    Config("sf_4gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 4}),
    Config("sf_2gpu_320x240_it1000", "sort_first.toml", {"scene.width": 320, "scene.height": 240,
                                                         "iterations": 1000}),
    Config("sf_2gpu_128x96_it6000", "sort_first.toml", {"scene.width": 128, "scene.height": 96,
                                                        "iterations": 6000}),
    Config("sl_1gpu_256x192_t20k", "sort_last.toml", {"schedule.gpus": 1}),
    Config("sl_3gpu_256x192_t20k", "sort_last.toml", {"schedule.gpus": 3}),
    Config("sl_2gpu_320x240_t60k", "sort_last.toml", {"scene.width": 320, "scene.height": 240,
                                                      "triangles": 60000}),
    Config("sl_2gpu_128x96_t5k", "sort_last.toml", {"scene.width": 128, "scene.height": 96,
                                                    "triangles": 5000}),
    Config("sf_2gpu_shared_host", "sort_first.toml", {"schedule.host_copy": False}),
]


def measure_all(out: Path, progress: Callable[[str], None]) -> list[Path]:
    """Run every sweep on lavapipe; write one table (+ machine record) per pass."""
    from .vulkan import measure as m  # noqa: PLC0415 - Vulkan only when measuring
    from .vulkan.machine import close_gpus, machine_record, make_gpus  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    gpus = make_gpus(1)
    try:
        for name, sweeps in SWEEPS:
            progress(f"measure {name}")
            df = m.measure(name, gpus, sweeps, reps=5, warmup=2)
            path = out / f"{name}.csv"
            m.write_table(df, str(path))
            record = machine_record(gpus, {"pass": name, "sweeps": sweeps, "reps": 5, "warmup": 2,
                                           "command": "mgpusim main (mgpusim/mainjob.py SWEEPS)"})
            path.with_name(path.name + ".machine.json").write_text(json.dumps(record, indent=2, default=str))
            paths.append(path)
    finally:
        close_gpus(gpus)
    return paths


def experiment_for(config: Config, profile: Path):
    """The config's experiment with its overrides; `iterations` / `triangles` set the pass."""
    overrides = {k: v for k, v in config.overrides.items()
                 if k not in ("iterations", "triangles")}
    exp = load_experiment(EXPERIMENTS / config.experiment, overrides, profile=profile)
    for key in ("iterations", "triangles"):
        if key in config.overrides:
            raw = json.loads(json.dumps(exp.raw))
            raw["scene"]["passes"][0][key] = config.overrides[key]
            from .experiment import parse_experiment  # noqa: PLC0415
            exp = parse_experiment(raw, exp.file, base=(EXPERIMENTS / config.experiment).parent,
                                   profile=exp.profile)
    return exp


def validate_all(configs: list[Config], profile: Path, out: Path,
                 progress: Callable[[str], None], measured_root: Path | None = None) -> pd.DataFrame:
    from .commands.validate import format_report, validate_experiment  # noqa: PLC0415

    rows = []
    for config in configs:
        progress(f"validate {config.name}")
        exp = experiment_for(config, profile)
        measured = measured_root / config.name / "measured" if measured_root else None
        report = validate_experiment(exp, out / config.name, measured)
        report["config"] = config.name
        progress(format_report(exp, report))
        rows.append(report)
    return error_table(rows)


def write_report(out: Path, table: pd.DataFrame, fit_text: str, held_out: bool) -> Path:
    stats = error_stats(table)
    lines = ["# mgpusim main job: measured vs simulated on lavapipe", "",
             "Errors are simulated / measured - 1. Each configuration's folder holds `timelines.png` "
             "(measured above simulated) and both Perfetto traces.", "",
             _markdown(table), "",
             f"Median |frame-time error| {stats['median_abs_frame_time_error']:.1%}, worst "
             f"{stats['worst_abs_frame_time_error']:.1%} over {stats['configurations']} configurations"
             + (" (calibrated on single-GPU microbenchmarks only: all are held out)." if held_out else "."),
             "", "## Calibration", "", "```", fit_text, "```", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    (out / "errors.csv").write_text(table.to_csv(index=False))
    (out / "errors.json").write_text(json.dumps(stats, indent=2))
    return path


def _markdown(table: pd.DataFrame) -> str:
    head = "| config | measured frame (ms) | simulated | error | measured latency (ms) | simulated | error |"
    rows = [head, "|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        rows.append(f"| {r.config} | {r.measured_frame_ms:.2f} | {r.simulated_frame_ms:.2f} | "
                    f"{r.frame_time_error:+.1%} | {r.measured_latency_ms:.2f} | {r.simulated_latency_ms:.2f} | "
                    f"{r.latency_error:+.1%} |")
    return "\n".join(rows)
