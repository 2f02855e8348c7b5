"""How building a pipelining program scales with copy chunks (it must stay linear: the
largest allowed count, schedule.chunks = 1024, builds in well under a second).

    PYTHONPATH=. python benchmarks/program_build.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim import load_experiment  # noqa: E402
from mgpusim.sim.simulation import build_program  # noqa: E402


def main() -> None:
    path = ROOT / "experiments" / "pipelining_miniengine_pcie3x8.toml"
    print(f"{'chunks':>7} {'tasks/frame':>12} {'build (s)':>10}")
    for chunks in (16, 64, 256, 1024):
        exp = load_experiment(path, {"schedule.chunks": chunks})
        start = time.perf_counter()
        program = build_program(exp)
        took = time.perf_counter() - start
        print(f"{chunks:>7} {len(program.templates[0]):>12} {took:>10.3f}")


if __name__ == "__main__":
    main()
