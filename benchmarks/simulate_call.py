"""Time one `simulate()` call of every shipped experiment, as a user's script or notebook makes
it: `analytic` and `full` (with the fast-forward), the experiment loaded once beforehand, the
summary read (what a sweep keeps) and nothing else: the trace and frames tables are built only
when read. The fastest of repeated calls (after one warm-up call) is printed, as the calling
process's CPU time and as wall time: on a machine shared with other work the CPU time is the
call's own cost, wall time also counts the neighbours (the two agree on an idle machine).

    PYTHONPATH=. python benchmarks/simulate_call.py [--repeat N] [--only NAME ...]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim import load_experiment, simulate  # noqa: E402


def shipped() -> list[Path]:
    return [p for p in sorted(ROOT.glob("experiments/**/*.toml")) if "[schedule]" in p.read_text()]


def call_ms(exp, fidelity: str, repeat: int) -> tuple[float, float]:
    """Fastest (CPU ms, wall ms) of simulate(exp, fidelity) with its summary read."""
    simulate(exp, fidelity=fidelity).summary  # noqa: B018 (warm-up: imports, caches)
    cpu, wall = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        simulate(exp, fidelity=fidelity).summary  # noqa: B018
        cpu.append(time.process_time() - start_cpu)
        wall.append(time.perf_counter() - start)
    return min(cpu) * 1e3, min(wall) * 1e3


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--only", nargs="*", default=None)
    args = p.parse_args()
    print(f"{'experiment':<44} {'frames':>6} {'analytic ms (CPU, wall)':>24} {'full ms (CPU, wall)':>20}")
    worst = {"analytic": [0.0, 0.0], "full": [0.0, 0.0]}
    for path in shipped():
        name = str(path.relative_to(ROOT / "experiments"))
        if args.only and not any(o in name for o in args.only):
            continue
        exp = load_experiment(path)
        cells = []
        for fidelity in ("analytic", "full"):
            try:
                cpu, wall = call_ms(exp, fidelity, args.repeat)
            except Exception as exc:  # noqa: BLE001 (a level the experiment refuses, e.g. vsync)
                cells.append(f"({type(exc).__name__})")
                continue
            worst[fidelity] = [max(worst[fidelity][0], cpu), max(worst[fidelity][1], wall)]
            cells.append(f"{cpu:.2f}, {wall:.2f}")
        print(f"{name:<44} {exp.schedule.frames:>6} {cells[0]:>24} {cells[1]:>20}", flush=True)
    print(f"{'slowest':<44} {'':>6} {worst['analytic'][0]:>11.2f}, {worst['analytic'][1]:.2f}"
          f" {worst['full'][0]:>13.2f}, {worst['full'][1]:.2f}")


if __name__ == "__main__":
    main()
