"""How long `mgpusim advise` takes as a frame's pass count grows (target: a 200-pass frame
under 60 s on 2 cores, or refused up front: it is refused, past advise's pass limit).

    PYTHONPATH=. python benchmarks/advise_passes.py [--passes 200] [--workers 2] [--out DIR]
    PYTHONPATH=. python benchmarks/advise_passes.py --passes 50 --frame-only --out f50.toml

Why a generated frame: engines with hundreds of passes (every shadow cascade, mip and blur a
pass of its own) are the captures where the search's cost shows, since frame pipelining
alone has a split point per pass. The frame repeats the 20-pass deferred renderer of
benchmarks/advise_speed.py (its passes renamed per copy, each copy reading its own targets, the
TAA of each reading its own last output), with every pass's time divided by the number of
copies so that the frame stays about 11 ms, imported from CSV as a user would. The whole
command runs: the search, the confirmation at full fidelity and the report with three timelines.
With --frame-only it writes the experiment to --out and stops (to compare advice by hand).
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

from mgpusim.bench.advise_frame import frame_csv  # noqa: E402
from mgpusim.cli import main as cli  # noqa: E402


def make_frame(passes: int, folder: Path, out: Path | None = None) -> Path:
    """The generated frame as an experiment (imported with `mgpusim frame import`)."""
    csv = folder / f"frame{passes}.csv"
    csv.write_text(frame_csv(passes))
    exp = out or folder / f"frame{passes}.toml"
    code = cli(["frame", "import", str(csv), "--size", "2560x1440", "--out", str(exp),
                "--profile", str(ROOT / "hardware_profiles" / "pcie4_pair.toml")])
    if code != 0:
        sys.exit(code)
    return exp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--passes", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--frame-only", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.frame_only:
            print(f"wrote {make_frame(args.passes, Path(tmp), args.out)}")
            return
        exp = make_frame(args.passes, Path(tmp))
        out = args.out or Path(tmp) / "advice"
        start = time.perf_counter()
        code = cli(["advise", str(exp), "--out", str(out), "--workers", str(args.workers)])
        took = time.perf_counter() - start
    what = "refused up front (past the pass limit)" if code == 2 else "report included"
    print(f"advise on a {args.passes}-pass frame: {took:.1f} s with {args.workers} worker(s) "
          f"on {os.cpu_count()} CPU(s), {what} (target: under 60 s on 2 cores, or refused up front)")
    sys.exit(code)


if __name__ == "__main__":
    main()
