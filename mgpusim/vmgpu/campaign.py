"""The grid of vmgpu configurations, its calibration and held-out halves, the interleaved order of
its repeats, and the loop that runs them with the speed probe before each run.

Why interleaved: the machine's speed drifts over minutes, and repeats run back to back would
share one speed and hide that drift inside a configuration's spread; round-robin rounds, each in a
fresh shuffled order, spread the drift over all configurations alike. Why the halves are fixed
by rule before any run: a model calibrated on one half and checked on the other is only honest if
nobody chose the halves after seeing the times.
"""
from __future__ import annotations

import random
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pandas as pd

from mgpusim.vmgpu import launch, logs, meshes
from mgpusim.vmgpu.build_folder import Build
from mgpusim.vmgpu.failures import VmgpuMeasureError
from mgpusim.vmgpu.launch import Config
from mgpusim.vmgpu.speed import Probe

HALF_RULE = ("a configuration is 'calibration' when the position of its triangle count in the "
             "sorted list of triangle counts plus the position of its resolution in the sorted "
             "list of resolutions (by pixel count) is even, else 'held-out' (a checkerboard over "
             "triangles x resolution: every strategy and GPU count is in both halves)")


@dataclass(frozen=True)
class Grid:
    """The asked-for axes. Sort-first and sort-last need 2 or more GPUs (vmgpu runs them as
    single on one) and single uses one, so only those points are run."""

    strategies: tuple[str, ...]
    gpus: tuple[int, ...]
    triangles: tuple[int, ...]
    resolutions: tuple[tuple[int, int], ...]
    simulate: bool = True

    def configs(self) -> list[Config]:
        """Every configuration to run, in a fixed order."""
        out = []
        for strategy in self.strategies:
            counts = [1] if strategy == "single" else [g for g in self.gpus if g >= 2]
            for gpus in counts:
                for tris in self.triangles:
                    for width, height in self.resolutions:
                        out.append(Config(strategy, gpus, tris, width, height, self.simulate))
        if not out:
            raise VmgpuMeasureError("the grid has no configuration to run (sort-first and "
                                    "sort-last need --gpus of 2 or more)")
        return out

    def half(self, config: Config) -> str:
        """'calibration' or 'held-out', by `HALF_RULE`."""
        tris = sorted(set(self.triangles)).index(config.triangles)
        res = sorted(set(self.resolutions), key=lambda r: (r[0] * r[1], r)).index(
            (config.width, config.height))
        return "calibration" if (tris + res) % 2 == 0 else "held-out"


def schedule(configs: list[Config], repeats: int, seed: int) -> list[tuple[int, Config]]:
    """(repeat, config) in run order: `repeats` rounds over every configuration, each round in
    its own seeded shuffle, no configuration twice in a row across two rounds."""
    rng = random.Random(seed)
    order: list[tuple[int, Config]] = []
    for repeat in range(repeats):
        round_ = list(configs)
        rng.shuffle(round_)
        if order and len(round_) > 1 and round_[0] == order[-1][1]:
            round_[0], round_[1] = round_[1], round_[0]
        order += [(repeat, c) for c in round_]
    return order


@dataclass
class Settings:
    """How each run is measured."""

    frames: int
    warmup: int
    repeats: int
    timeout_s: float
    stall_factor: float = logs.STALL_FACTOR
    seed: int = 0
    log_dir: Path | None = None
    driver: str = "lavapipe"


@dataclass
class Results:
    """The campaign's tables, built in memory and written only once it is complete."""

    runs: list[dict[str, object]] = field(default_factory=list)
    frames: list[pd.DataFrame] = field(default_factory=list)
    end_probe: dict[str, float] = field(default_factory=dict)


def run_campaign(build: Build, grid: Grid, settings: Settings, display: str, mesh_dir: Path,
                 probe: Probe, progress: Callable[[str], None] = lambda s: print(s, file=sys.stderr),
                 xvfb_pid: int | None = None) -> Results:
    """Every run of the grid in interleaved order; the first failed run ends it with
    RunFailedError (no retry, no partial table)."""
    if settings.warmup >= settings.frames:
        raise VmgpuMeasureError(f"--warmup {settings.warmup} leaves no frame of --frames "
                                f"{settings.frames} to measure")
    configs = grid.configs()
    mesh_files = {t: meshes.sphere_file(mesh_dir, t) for t in sorted(set(grid.triangles))}
    order = schedule(configs, settings.repeats, settings.seed)
    results = Results()
    for position, (repeat, config) in enumerate(order):
        label = f"{position + 1}/{len(order)} ({config.key}, repeat {repeat + 1})"
        progress(f"run {label}")
        speed = probe.measure()
        row, frames = _one_run(build, config, mesh_files[config.triangles], display, settings,
                               label, xvfb_pid)
        row.update({"run": position, "repeat": repeat, "config": config.key,
                    "half": grid.half(config), "probe_fragment_ms": speed.get("fragment_loop"),
                    "probe_mesh_ms": speed.get("mesh")})
        frames.insert(0, "run", position)
        frames.insert(1, "config", config.key)
        results.runs.append(row)
        results.frames.append(frames)
        progress(f"  median {row['median_ms']:.2f} ms, IQR {row['iqr_ms']:.2f} ms, "
                 f"stalls {row['stalls']}, load {row['load_before']:.2f}")
    results.end_probe = probe.measure()
    return results


def _one_run(build: Build, config: Config, mesh: meshes.MeshFile, display: str,
             settings: Settings, label: str, xvfb_pid: int | None,
             ) -> tuple[dict[str, object], pd.DataFrame]:
    """One checked run: its summary row and its per-frame table."""
    record = launch.run(build, config, mesh.path, display, settings.frames, settings.timeout_s,
                        label, xvfb_pid, settings.driver)
    if settings.log_dir is not None:
        settings.log_dir.mkdir(parents=True, exist_ok=True)
        (settings.log_dir / f"{label.split()[0].replace('/', '_of_')}_{config.key}.log").write_text(
            record.text)
    expected = logs.Expected(frames=settings.frames, gpus=config.gpus, triangles=mesh.triangles)
    log = logs.check(label, record.returncode, record.text, expected)
    stats = logs.summary(log.frames, settings.warmup, settings.stall_factor)
    frames = log.frames.drop(columns="frames_in_line")
    frames["warmup"] = frames["frame"] < settings.warmup
    median = float(frames.loc[~frames["warmup"], "period_ms"].median())
    frames["stall"] = ~frames["warmup"] & (frames["period_ms"] > settings.stall_factor * median)
    measured_s = float(frames["period_ms"].sum()) / 1000
    row: dict[str, object] = {
        "strategy": config.strategy, "gpus": config.gpus, "triangles": config.triangles,
        "width": config.width, "height": config.height, "driver": settings.driver,
        "simulate_mgpu": config.simulate, "frames": settings.frames,
        "warmup": settings.warmup, **stats,
        "startup_s": record.wall_s - measured_s, "wall_s": record.wall_s,
        "vmgpu_cpu_s": record.vmgpu_cpu_s, "vmgpu_cores": record.vmgpu_cpu_s / record.wall_s,
        "xvfb_cpu_s": record.xvfb_cpu_s, "other_cores": record.other_cores,
        "steal_cores": record.steal_cores, "load_before": record.load_before,
        "load_after": record.load_after, "unix_start": round(record.unix_start, 1),
        "gpu_names": "; ".join(log.gpus), "mesh_vertices": mesh.vertices,
        "fps_printed_median": float(pd.Series(log.fps).median()) if log.fps else float("nan"),
    }
    return row, frames

