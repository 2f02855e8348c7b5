"""Points per second of `mgpusim sweep` through the CLI: the wall time of the whole command in a
fresh process (imports, points, the table, plot and description written), on six grids:

- `lanes`: 100,000 points, 10 scene widths (group keys) x 10^4 pass-cost combinations (lanes),
  TC1 sort-first (60 frames), `--fidelity analytic`;
- `mixed`: 100,000 points, a scene key and a profile key that is not a pass cost
  (`profile.host.memcpy_thread_gbps`) as group keys (100 groups) x 1,000 pass-cost lanes;
- `scene`: 2,000 points over two scene keys only (width x height): every point its own
  program, built and run as a lane of its own (the rate the group keys alone give);
- `scene-gpus`: 3,000 points over two scene keys and the GPU count (40 x 25 x 3): every
  point its own program, of three structures;
- `scene-large`: 20,000 points over two scene keys (200 x 100): the rate past the command's
  fixed cost (imports, the plot's matplotlib, the table: about 0.8 s);
- `full`: 400 points at `--fidelity full` (the default) with the fast-forward, 1,000 frames
  each (TC1 sort-first: the state repeats from frame 92), over a pass cost and the width: one
  event simulation per point, on every CPU;
- `full-afr`: 4,000 points at `--fidelity full`, 10,000 frames each of TC1 AFR on one GPU
  (the state repeats from frame 1): what a point costs besides its event simulation.

    PYTHONPATH=. python benchmarks/sweep_cli.py [--only lanes mixed ...] [--runs 1] [--tree DIR ...]

The machine is a shared 2-core VM whose speed moves 10-130 % within minutes: before and after
each command a fixed pure-Python reference loop is timed, and each figure is printed as
measured (wall and CPU seconds, points/s), as points per reference loop (points/s x the loop's
seconds after the command) and scaled to the fastest the reference loop ran in this run ("at
reference speed": points/s x the loop's time then / its fastest time). `--tree` runs each
grid with other checkouts' mgpusim as well, in turn (before and after a change, in one run).
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "sort_first_tc1.toml"
WIDTHS = "scene.width=640,800,960,1024,1280,1440,1600,1920,2560,3840"
SPEEDS = "profile.gpus.*.speed=0.5,0.75,1,1.25,1.5,2,2.5,3,4,5"
PIXEL = ("profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration="
         "0.0008,0.001,0.0012,0.0014,0.0016,0.0018,0.002,0.0024,0.003,0.004")
FIXED = "profile.gpus.*.costs.fragment_loop.fixed_ns=0,5000,10000,20000,30000,40000,50000,60000,80000,100000"
COMPOSITE = ("profile.gpus.*.costs.composite_sort_first.fixed_ns="
             "0,2500,5000,10000,15000,20000,30000,40000,60000,80000")
GRIDS: dict[str, tuple[list[str], list[str]]] = {  # name -> (grids, other arguments)
    "lanes": ([WIDTHS, SPEEDS, PIXEL, FIXED, COMPOSITE], ["--fidelity", "analytic"]),
    "mixed": ([WIDTHS, "profile.host.memcpy_thread_gbps=4,5,6,7,8,9,10,11,12,13", SPEEDS, PIXEL, FIXED],
              ["--fidelity", "analytic"]),
    "scene": (["scene.width=" + ",".join(str(600 + 8 * i) for i in range(50)),
               "scene.height=" + ",".join(str(400 + 6 * i) for i in range(40))], ["--fidelity", "analytic"]),
    "scene-gpus": (["scene.width=" + ",".join(str(600 + 8 * i) for i in range(40)),
                    "scene.height=" + ",".join(str(400 + 6 * i) for i in range(25)), "schedule.gpus=1,2,3"],
                   ["--fidelity", "analytic"]),
    "scene-large": (["scene.width=" + ",".join(str(600 + 4 * i) for i in range(200)),
                     "scene.height=" + ",".join(str(400 + 3 * i) for i in range(100))], ["--fidelity", "analytic"]),
    "full": (["profile.gpus.*.speed=" + ",".join(f"{0.5 + 0.1 * i:g}" for i in range(10)),
              "scene.width=" + ",".join(str(700 + 10 * i) for i in range(40))],
             ["--set", "schedule.frames=1000"]),
    "full-afr": (["profile.gpus.*.speed=" + ",".join(f"{0.5 + 0.01 * i:g}" for i in range(100)),
                  "scene.width=" + ",".join(str(700 + 10 * i) for i in range(40))],
                 ["--set", "schedule.gpus=1", "--set", "schedule.frames=10000"]),
}
#: The experiment of each grid (default: EXPERIMENT).
EXPERIMENTS = {"full-afr": ROOT / "experiments" / "afr_tc1.toml"}


def reference_loop() -> float:
    """Seconds of a fixed pure-Python loop (dict and list work, as the model's)."""
    t0 = time.perf_counter()
    d: dict[int, int] = {}
    acc = []
    for i in range(300_000):
        d[i & 1023] = d.get(i & 1023, 0) + i
        acc.append(i ^ (i >> 3))
    return time.perf_counter() - t0 + 0 * len(acc)


def run_cli(grid: list[str], extra: list[str], out: Path, experiment: Path = EXPERIMENT,
            tree: Path = ROOT) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds of the command and its workers, points) of one `mgpusim
    sweep` into a fresh folder, with the `mgpusim` of checkout `tree`."""
    args = [sys.executable, "-m", "mgpusim", "sweep", str(experiment), "--no-progress", "--out", str(out), *extra]
    for item in grid:
        args += ["--grid", item]
    env = {**os.environ, "PYTHONPATH": str(tree)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(args, env=env, check=True, capture_output=True, cwd=tree)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, len(pd.read_parquet(out / "sweep.parquet", columns=["point"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", choices=sorted(GRIDS), default=list(GRIDS), help="grids to time")
    parser.add_argument("--runs", type=int, default=1, help="runs of each grid (default 1)")
    parser.add_argument("--tree", type=Path, action="append", default=None, metavar="DIR",
                        help="a checkout whose mgpusim runs the sweeps (repeatable: each grid runs in each "
                             "tree in turn, e.g. the tree before a change beside this one); default: this one")
    args = parser.parse_args()
    trees = [t.resolve() for t in args.tree or [ROOT]]
    refs = [min(reference_loop() for _ in range(3))]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only:
            grid, extra = GRIDS[name]
            for i in range(args.runs):
                for k, tree in enumerate(trees):
                    experiment = EXPERIMENTS.get(name, EXPERIMENT)
                    wall, cpu, points = run_cli(grid, extra, Path(tmp) / f"{name}{i}-{k}",
                                                tree / experiment.relative_to(ROOT), tree)
                    ref = min(reference_loop() for _ in range(3))
                    refs.append(ref)
                    results.append((name, i, tree, wall, cpu, points, ref))
    best = min(refs)
    print(f"reference loop: fastest {best * 1e3:.1f} ms, slowest {max(refs) * 1e3:.1f} ms in this run "
          f"({os.cpu_count()} CPUs)")
    for name, i, tree, wall, cpu, points, ref in results:
        scale = ref / best
        where = f" [{tree}]" if len(trees) > 1 else ""
        print(f"{name:10s} run {i + 1}{where}: {points:,} points in {wall:.2f} s wall ({cpu:.2f} s CPU) = "
              f"{points / wall:,.0f} points/s, {points / wall * ref:,.1f} points per reference loop; "
              f"at reference speed {points / wall * scale:,.0f} points/s (loop {scale:.2f}x its fastest)")


if __name__ == "__main__":
    main()
