"""How long `mgpusim advise` takes on a 20-pass frame searched over every option (target:
under 10 s on 2 cores), and as a multiple of the reference loop timed before and after it
(mgpusim.bench.reference.reference_loop: the machine's speed moves within minutes).

    PYTHONPATH=. python benchmarks/advise_speed.py [--workers 2] [--out DIR]

The frame: mgpusim.bench.advise_frame's 20 passes at 2560x1440, imported from CSV as a user
would. The whole command runs: the search at the analytic level, the confirmation at full
fidelity and the report with three timelines.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.bench.advise_frame import PASSES, frame20_csv  # noqa: E402
from mgpusim.bench.reference import reference_loop  # noqa: E402
from mgpusim.cli import main as cli  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "advice"
        csv = Path(tmp) / "frame20.csv"
        csv.write_text(frame20_csv())
        exp = Path(tmp) / "frame20.toml"
        cli(["frame", "import", str(csv), "--size", "2560x1440", "--out", str(exp),
             "--profile", str(ROOT / "hardware_profiles" / "pcie4_pair.toml")])
        ref = min(reference_loop() for _ in range(3))
        start = time.perf_counter()
        code = cli(["advise", str(exp), "--out", str(out), "--workers", str(args.workers)])
        took = time.perf_counter() - start
        ref = min(ref, *(reference_loop() for _ in range(3)))
    print(f"advise on a {len(PASSES)}-pass frame: {took:.1f} s with {args.workers} worker(s) "
          f"on {os.cpu_count()} CPU(s), report included = {took / ref:.0f} reference loops of "
          f"{ref * 1e3:.0f} ms (target: under 10 s on 2 cores)")
    sys.exit(code)


if __name__ == "__main__":
    main()
