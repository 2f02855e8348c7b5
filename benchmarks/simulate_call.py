"""Time one `simulate()` call of every shipped experiment, as a user's script or notebook makes
it: `analytic` and `full` (with the fast-forward), the experiment loaded once beforehand, the
summary read (what a sweep keeps) and nothing else: the trace and frames tables are built only
when read. The fastest of repeated calls (after one warm-up call) is printed: on a machine
shared with other work the minimum is the call's own cost, a median also measures the
neighbours.

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


def call_ms(exp, fidelity: str, repeat: int) -> float:
    """Fastest ms of simulate(exp, fidelity) with its summary read."""
    simulate(exp, fidelity=fidelity).summary  # noqa: B018 (warm-up: imports, caches)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        simulate(exp, fidelity=fidelity).summary  # noqa: B018
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--only", nargs="*", default=None)
    args = p.parse_args()
    print(f"{'experiment':<48} {'frames':>6} {'analytic ms':>12} {'full ms':>8}")
    worst = {"analytic": 0.0, "full": 0.0}
    for path in shipped():
        name = str(path.relative_to(ROOT / "experiments"))
        if args.only and not any(o in name for o in args.only):
            continue
        exp = load_experiment(path)
        row = {}
        for fidelity in ("analytic", "full"):
            try:
                row[fidelity] = call_ms(exp, fidelity, args.repeat)
                worst[fidelity] = max(worst[fidelity], row[fidelity])
            except Exception as exc:  # noqa: BLE001 (a level the experiment refuses, e.g. vsync)
                row[fidelity] = None
                refused = type(exc).__name__
        cells = [f"{row[f]:.2f}" if row[f] is not None else f"({refused})" for f in ("analytic", "full")]
        print(f"{name:<48} {exp.schedule.frames:>6} {cells[0]:>12} {cells[1]:>8}", flush=True)
    print(f"{'slowest':<48} {'':>6} {worst['analytic']:>12.2f} {worst['full']:>8.2f}")


if __name__ == "__main__":
    main()
