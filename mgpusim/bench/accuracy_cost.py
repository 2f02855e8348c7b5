"""What accuracy costs in time: every committed measured configuration at every fidelity level.

The measured runs are those committed with the studies (`experiments/*/study.toml`: each entry
an experiment file and `--set` items, its run folder, the calibrated profile). Each
configuration is simulated at each level; the error is simulated / measured - 1 of the
steady-state frame time and latency (both sides through the same summary code, the
experiment's warm-up). Wall time is that of `simulate()` (model plus tables) and of the model
alone (the event engine or the analytic recurrence).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import pandas as pd

from mgpusim.io.shipped import examples, shipped_dir
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.tasks import QueueRef
from mgpusim.results.summary import Result
from mgpusim.schedules.experiment import Experiment, load_experiment
from mgpusim.sim.simulation import build_program, simulate
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.study_file import load_study
from mgpusim.validation.compare import rel_error, steady_summary
from mgpusim.validation.measured import queues_as_run, read_measured

EXPERIMENTS = shipped_dir("experiments")
PROFILES = shipped_dir("hardware_profiles")


@dataclass(frozen=True)
class Source:
    """Measured runs of a study: the folders holding its entries' runs, simulated on `profile`
    (the study's own when None)."""

    name: str
    study: Path
    runs: tuple[Path, ...]
    profile: Path | None = None


def committed_sources(data: Path) -> tuple[Source, ...]:
    """The measured runs committed in a checkout's `data/` folder: the H200 study's calibration
    and held-out runs, the H100's 1-GPU runs of the same study, and the steady windows of the
    lavapipe main job of 2026-11-24 with the profile that job fitted. `data` is given by the
    caller (a wheel has no measured data): a folder that lacks them is one clear error."""
    lavapipe = data / "lavapipe" / "history" / "main_job_2026-11-24"
    sources = (
        Source("2x H200", EXPERIMENTS / "h200/study.toml",
               (data / "nvidia/h200_x2/runs_2026-11-27",)),
        Source("H100", EXPERIMENTS / "h200/study.toml", (data / "nvidia/h100_x1/runs_1gpu",),
               PROFILES / "h100.toml"),
        Source("lavapipe", EXPERIMENTS / "lavapipe/study.toml", (lavapipe / "runs",),
               lavapipe / "profile.toml"),
    )
    for src in sources:
        for folder in (*src.runs, *([src.profile] if src.profile else [])):
            if not folder.exists():
                raise InputError(f"{data} lacks the committed measured runs ({folder} is missing);"
                                 f" pass a checkout's data/ folder", field="--data")
    return sources


@dataclass(frozen=True)
class Configuration:
    source: str
    name: str
    experiment: Experiment
    measured: pd.DataFrame  # the measured trace
    #: the queues the run replaced by another (the runner's one queue per family), as
    #: `mgpusim validate` simulates them: every level is compared with the schedule as it ran
    queues: Mapping[QueueRef, QueueRef] = field(default_factory=dict)


def configurations(sources: tuple[Source, ...]) -> list[Configuration]:
    """Every entry of every source that has a measured run folder."""
    out = []
    for src in sources:
        study = load_study(src.study)
        for entry in study.entries():
            folder = next((f for f in (measured_folder(root, entry.name) for root in src.runs)
                           if run_archive.is_folder(f)), None)
            if folder is None:
                continue
            exp = entry.load(src.profile or study.profile)
            measured = read_measured(folder, exp)
            out.append(Configuration(src.name, entry.name, exp, measured,
                                     queues_as_run(measured, build_program(exp))))
    return out


def measured_summary(config: Configuration) -> dict[str, Any]:
    return steady_summary(config.measured, config.experiment.schedule.warmup_frames)


#: What is compared: the three levels, and full without the fast-forward (what it saves).
VARIANTS: dict[str, dict[str, Any]] = {
    "analytic": {"fidelity": "analytic"},
    "queues": {"fidelity": "queues"},
    "full": {"fidelity": "full"},
    "full, no fast-forward": {"fidelity": "full", "fast_forward": False},
}


def run_levels(configs: list[Configuration], variants: dict[str, dict[str, Any]] | None = None,
               repeats: int = 3, progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """One row per (configuration, level): errors against the measured run and wall time
    (best of `repeats`). `progress(name)`: called before each (configuration, level)."""
    rows = []
    for c in configs:
        measured = measured_summary(c)
        for level, kwargs in (variants or VARIANTS).items():
            if progress is not None:
                progress(f"{c.name} at {level}")
            wall, model, result = float("inf"), float("inf"), None
            for _ in range(repeats):
                t0 = time.perf_counter()
                result = simulate(c.experiment, record_trace=False, queues=c.queues, **kwargs)
                wall = min(wall, time.perf_counter() - t0)
                model = min(model, _model_s(result))
            assert result is not None  # repeats >= 1
            s = result.summary
            rows.append({"machine": c.source, "config": c.name, "schedule": c.experiment.schedule.name,
                         "gpus": c.experiment.schedule.gpus, "level": level,
                         "measured_frame_ms": measured["frame_time_ms"], "frame_ms": s["frame_time_ms"],
                         "frame_time_error": rel_error(s["frame_time_ms"], measured["frame_time_ms"]),
                         "latency_error": rel_error(s["latency_ms"], measured["latency_ms"]),
                         "wall_ms": wall * 1e3, "model_ms": model * 1e3})
    return pd.DataFrame(rows)


def _model_s(result: Result) -> float:
    """The model's own time of a run (simulate sets it)."""
    assert result.model_wall_s is not None
    return result.model_wall_s


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
    r: Any  # a row's fields (pandas-stubs types each as any scalar)
    for r in summary.itertuples(index=False):
        lines.append(f"| {r.level} | {r.schedule} | {r.configurations} | "
                     f"{100 * r.median_abs_frame_time_error:.1f} % / {100 * r.worst_abs_frame_time_error:.1f} % | "
                     f"{100 * r.median_abs_latency_error:.1f} % / {100 * r.worst_abs_latency_error:.1f} % | "
                     f"{r.median_wall_ms:.2f} | {r.median_model_ms:.2f} |")
    return "\n".join(lines) + "\n"


def deviations(variants: dict[str, dict[str, Any]] | None = None, repeats: int = 3,
               progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Where there is no measurement: each level's frame time against `full` on the shipped
    experiments, and the model's time (best of `repeats`). `progress(name)`: called before
    each (experiment, level)."""
    rows = []
    for example in examples():
        exp = load_experiment(example.path)
        for level, kwargs in (variants or VARIANTS).items():
            if progress is not None:
                progress(f"{example.name} at {level}")
            model, result = float("inf"), None
            for _ in range(repeats):
                result = simulate(exp, record_trace=False, **kwargs)
                model = min(model, _model_s(result))
            assert result is not None  # repeats >= 1
            ft = result.summary["frame_time_ms"]
            rows.append({"experiment": example.name, "level": level,
                         "frame_ms": ft, "model_ms": model * 1e3})
    table = pd.DataFrame(rows)
    full = table[table.level == "full"].set_index("experiment")["frame_ms"]
    table["deviation_from_full"] = table["frame_ms"] / table["experiment"].map(full) - 1
    return table


def summarize_deviations(table: pd.DataFrame) -> pd.DataFrame:
    out = []
    for level, g in table.groupby("level", sort=False):
        dev = g["deviation_from_full"].abs().to_numpy()
        out.append({"level": level, "experiments": len(g), "median_abs_deviation": float(np.median(dev)),
                    "worst_abs_deviation": float(dev.max()),
                    "worst_experiment": str(g.iloc[int(dev.argmax())]["experiment"]) if dev.max() > 0 else "-",
                    "median_model_ms": float(g["model_ms"].median())})
    return pd.DataFrame(out)


def deviations_markdown(summary: pd.DataFrame) -> str:
    lines = ["| level | experiments | median / worst \\|frame time - full\\| | worst on | model ms (median) |",
             "|---|---|---|---|---|"]
    r: Any  # a row's fields (pandas-stubs types each as any scalar)
    for r in summary.itertuples(index=False):
        lines.append(f"| {r.level} | {r.experiments} | {100 * r.median_abs_deviation:.1f} % / "
                     f"{100 * r.worst_abs_deviation:.1f} % | {r.worst_experiment} | {r.median_model_ms:.2f} |")
    return "\n".join(lines) + "\n"
