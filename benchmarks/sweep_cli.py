"""Points per second of `mgpusim sweep --fidelity analytic` through the CLI: the wall time of
the whole command in a fresh process (imports, points, the table, plot and description
written), on a 100,000-point grid that runs as lanes, and on a smaller grid whose key cannot
(it runs point by point: the fallback's rate).

    PYTHONPATH=. python benchmarks/sweep_cli.py [--runs 2] [--fallback-points 200]

The 100k grid: 10 scene widths (group keys: built and run once each with the real code) times
10^4 combinations of four pass-cost keys (lanes) on TC1 sort-first (60 frames).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "sort_first_tc1.toml"
LANE_GRID = [
    "scene.width=640,800,960,1024,1280,1440,1600,1920,2560,3840",
    "profile.gpus.*.speed=0.5,0.75,1,1.25,1.5,2,2.5,3,4,5",
    "profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration="
    "0.0008,0.001,0.0012,0.0014,0.0016,0.0018,0.002,0.0024,0.003,0.004",
    "profile.gpus.*.costs.fragment_loop.fixed_ns=0,5000,10000,20000,30000,40000,50000,60000,80000,100000",
    "profile.gpus.*.costs.composite_sort_first.fixed_ns=0,2500,5000,10000,15000,20000,30000,40000,60000,80000",
]


def fallback_grid(points: int) -> list[str]:
    """`points` points over a key lanes cannot express (the memcpy threads' speed changes
    host copies, not pass costs) and the scene width."""
    gbps = ",".join(f"{4 + 0.5 * i:g}" for i in range(points // 10))
    return [f"profile.host.memcpy_thread_gbps={gbps}", "scene.width=640,800,960,1024,1280,1440,1600,1920,2560,3840"]


def run_cli(grid: list[str], out: Path) -> tuple[float, int, int]:
    """(wall seconds, points, batch files) of one `mgpusim sweep` into a fresh folder."""
    args = [sys.executable, "-m", "mgpusim", "sweep", str(EXPERIMENT), "--fidelity", "analytic",
            "--no-progress", "--out", str(out)]
    for item in grid:
        args += ["--grid", item]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    subprocess.run(args, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    points = len(pd.read_parquet(out / "sweep.parquet"))
    batches = sum(1 for n in os.listdir(out / "points") if n.startswith("batch-"))
    return wall, points, batches


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="runs of the 100k grid (default 2)")
    parser.add_argument("--fallback-points", type=int, default=200, help="points of the fallback grid")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            wall, points, batches = run_cli(LANE_GRID, Path(tmp) / f"lanes{i}")
            print(f"lanes, run {i + 1}: {points:,} points in {wall:.2f} s = {points / wall:,.0f} points/s "
                  f"({batches} batch files)")
        wall, points, batches = run_cli(fallback_grid(args.fallback_points), Path(tmp) / "fallback")
        print(f"fallback (profile.host.memcpy_thread_gbps x scene.width, point by point): {points:,} "
              f"points in {wall:.2f} s = {points / wall:,.0f} points/s ({batches} batch files)")


if __name__ == "__main__":
    main()
