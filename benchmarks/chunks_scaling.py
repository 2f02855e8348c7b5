"""Time and peak memory of frame pipelining as copies are split into more chunks: they must grow
linearly with the chunk count (a task's inputs are integer ids, not text per trace row).

For each chunk count: tasks per frame; `mgpusim simulate` of 10^4 frames with the fast-forward
and its default outputs (a fresh interpreter each: wall time and its peak resident memory); and
`simulate()` of the experiment's 60 frames with the fast-forward off and on (the speed-up it
gives at every chunk count).

    PYTHONPATH=. python benchmarks/chunks_scaling.py [CHUNKS ...]   (default 1 4 16 64 256 1024)
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim import load_experiment  # noqa: E402
from mgpusim.sim.simulation import build_program, simulate  # noqa: E402

EXPERIMENT = ROOT / "experiments" / "pipelining_miniengine_pcie3x8.toml"
FRAMES = 10_000
#: runs the CLI in this interpreter, then prints its own peak resident memory (KiB on Linux)
_CHILD = ("import resource, sys; from mgpusim.cli import main; code = main(sys.argv[1:]); "
          "print('PEAK_KIB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); "
          "sys.exit(code)")


def cli_run(chunks: int, out: Path) -> tuple[float, float]:
    """(wall seconds, peak MiB) of `mgpusim simulate` at `chunks`, 10^4 frames, default outputs."""
    args = ["simulate", str(EXPERIMENT), "--set", f"schedule.chunks={chunks}",
            "--set", f"schedule.frames={FRAMES}", "--out", str(out)]
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": ""})
    wall = time.perf_counter() - start
    if run.returncode:
        raise SystemExit(run.stdout + run.stderr)
    peak = next(int(line.split()[1]) for line in run.stderr.splitlines() if line.startswith("PEAK_KIB"))
    return wall, peak / 1024


def model_run(chunks: int, fast_forward: bool) -> float:
    """Seconds of one simulate() of the experiment's own 60 frames."""
    exp = load_experiment(EXPERIMENT, {"schedule.chunks": chunks})
    start = time.perf_counter()
    simulate(exp, fast_forward=fast_forward)
    return time.perf_counter() - start


def main(counts: list[int]) -> None:
    print(f"{EXPERIMENT.name}: mgpusim simulate, {FRAMES:,} frames, fast-forward, default outputs; "
          "simulate() of 60 frames")
    print(f"{'chunks':>7} {'tasks/frame':>12} {'CLI s':>7} {'peak MiB':>9} "
          f"{'60 fr, ff off s':>16} {'ff on s':>8} {'speed-up':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for chunks in counts:
            tasks = len(build_program(load_experiment(EXPERIMENT, {"schedule.chunks": chunks})).templates[0])
            wall, peak = cli_run(chunks, Path(tmp) / f"c{chunks}")
            off, on = model_run(chunks, False), model_run(chunks, True)
            print(f"{chunks:>7} {tasks:>12} {wall:>7.2f} {peak:>9.0f} {off:>16.2f} {on:>8.2f} {off / on:>8.1f}x",
                  flush=True)


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [1, 4, 16, 64, 256, 1024])
