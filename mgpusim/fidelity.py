"""What accuracy costs in time: every committed measured configuration at every fidelity level.

A *machine* is a folder of measured runs (`mgpusim run` folders, one per configuration), the
configuration list they were measured from (experiment file + `--set` items) and the calibrated
profile. Each configuration is simulated at each level; the error is simulated / measured - 1 of
the steady-state frame time and latency (both sides through the same summary code, the
experiment's warm-up). Wall time is that of `simulate()` (model plus tables) and of the model
alone (the event engine or the analytic recurrence).
"""
from __future__ import annotations

import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .experiment import Experiment, load_experiment, parse_overrides
from .simulate import simulate
from .validate import rel_error, steady_summary

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Machine:
    name: str
    configs: Path  # TOML: [[config]] name, experiment, set
    runs: Path  # one measured folder per configuration name
    profile: Path


#: The committed measured runs (no lavapipe steady runs are committed: the main job makes them).
MACHINES = (
    Machine("2x H200", ROOT / "experiments/h200/configs.toml", ROOT / "data/nvidia/h200x2/runs_si",
            ROOT / "hardware_profiles/h200_x2.toml"),
    Machine("H100", ROOT / "experiments/h200/configs.toml", ROOT / "data/nvidia/h100/runs_1gpu",
            ROOT / "hardware_profiles/h100.toml"),
)


@dataclass(frozen=True)
class Configuration:
    machine: str
    name: str
    experiment: Experiment
    measured: Path


def configurations(machines: tuple[Machine, ...] = MACHINES) -> list[Configuration]:
    """Every configuration of every machine that has a measured folder."""
    out = []
    for m in machines:
        for entry in tomllib.loads(m.configs.read_text())["config"]:
            folder = m.runs / entry["name"]
            if not (folder / "trace.csv").is_file():
                continue
            exp = load_experiment(m.configs.parent / entry["experiment"],
                                  parse_overrides(list(entry.get("set", ()))), profile=str(m.profile))
            out.append(Configuration(m.name, entry["name"], exp, folder))
    return out


def measured_summary(config: Configuration) -> dict[str, Any]:
    trace = pd.read_csv(config.measured / "trace.csv")
    return steady_summary(trace, config.experiment.schedule.warmup_frames)


#: What is compared: the three levels, and full without the fast-forward (what it saves).
VARIANTS: dict[str, dict[str, Any]] = {
    "analytic": {"fidelity": "analytic"},
    "queues": {"fidelity": "queues"},
    "full": {"fidelity": "full"},
    "full, no fast-forward": {"fidelity": "full", "fast_forward": False},
}


def run_levels(configs: list[Configuration], variants: dict[str, dict[str, Any]] | None = None,
               repeats: int = 3) -> pd.DataFrame:
    """One row per (configuration, level): errors against the measured run and wall time
    (best of `repeats`)."""
    rows = []
    for c in configs:
        measured = measured_summary(c)
        for level, kwargs in (variants or VARIANTS).items():
            wall, model, result = float("inf"), float("inf"), None
            for _ in range(repeats):
                t0 = time.perf_counter()
                result = simulate(c.experiment, record_trace=False, **kwargs)
                wall = min(wall, time.perf_counter() - t0)
                model = min(model, result.model_wall_s)
            s = result.summary
            rows.append({"machine": c.machine, "config": c.name, "schedule": c.experiment.schedule.name,
                         "gpus": c.experiment.schedule.gpus, "level": level,
                         "measured_frame_ms": measured["frame_time_ms"], "frame_ms": s["frame_time_ms"],
                         "frame_time_error": rel_error(s["frame_time_ms"], measured["frame_time_ms"]),
                         "latency_error": rel_error(s["latency_ms"], measured["latency_ms"]),
                         "wall_ms": wall * 1e3, "model_ms": model * 1e3})
    return pd.DataFrame(rows)


def summarize_levels(table: pd.DataFrame) -> pd.DataFrame:
    """Per level and schedule (and all schedules): median and worst |error|, wall time."""
    groups = []
    for (level, schedule), g in list(table.groupby(["level", "schedule"])) + [
            ((level, "all"), g) for level, g in table.groupby("level")]:
        ft, lat = g["frame_time_error"].abs().to_numpy(), g["latency_error"].abs().to_numpy()
        groups.append({"level": level, "schedule": schedule, "configurations": len(g),
                       "median_abs_frame_time_error": float(np.median(ft)),
                       "worst_abs_frame_time_error": float(ft.max()),
                       "median_abs_latency_error": float(np.median(lat)),
                       "worst_abs_latency_error": float(lat.max()),
                       "median_wall_ms": float(g["wall_ms"].median()),
                       "median_model_ms": float(g["model_ms"].median())})
    out = pd.DataFrame(groups)
    order = {lv: i for i, lv in enumerate(VARIANTS)}
    return out.sort_values(["level", "schedule"], key=lambda s: s.map(order) if s.name == "level" else s,
                           kind="stable").reset_index(drop=True)


def markdown(summary: pd.DataFrame) -> str:
    """The per-level table as Markdown (errors in %, times in ms)."""
    lines = ["| level | schedule | configurations | median / worst \\|frame-time error\\| | "
             "median / worst \\|latency error\\| | simulate() ms (median) | model ms (median) |",
             "|---|---|---|---|---|---|---|"]
    for r in summary.itertuples(index=False):
        lines.append(f"| {r.level} | {r.schedule} | {r.configurations} | "
                     f"{100 * r.median_abs_frame_time_error:.1f} % / {100 * r.worst_abs_frame_time_error:.1f} % | "
                     f"{100 * r.median_abs_latency_error:.1f} % / {100 * r.worst_abs_latency_error:.1f} % | "
                     f"{r.median_wall_ms:.2f} | {r.median_model_ms:.2f} |")
    return "\n".join(lines) + "\n"
