"""Peak memory of the largest allowed run: `mgpusim simulate` with its default outputs (summary,
trace, frames and links tables, timeline, Perfetto trace) at `schedule.frames` = N, each run in
a fresh process whose peak resident set size the system reports (`os.wait4`, the figure
`/usr/bin/time -v` prints as "Maximum resident set size").

    PYTHONPATH=. python benchmarks/largest_run_memory.py                 # the heaviest, at MAX_FRAMES
    PYTHONPATH=. python benchmarks/largest_run_memory.py --all           # every shipped one, at MAX_FRAMES
    PYTHONPATH=. python benchmarks/largest_run_memory.py experiments/afr_tc1.toml --frames 1000000

Prints one line per experiment (fast-forward used or not, wall time, peak RSS, output size)
and whether it stayed under the budget (1 GiB), then the largest peak and whether every run
stayed under the budget. A run killed for memory shows its exit code;
one above MAX_RECORDED_FRAMES frames that does not fast-forward is refused by the input rule
(`mgpusim/model/limits.py`) within seconds and shows "refused": not a run the bound allows,
so not counted against the budget. Its output folder is removed either way.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.model.limits import MAX_FRAMES  # noqa: E402

#: What the largest allowed run may take.
BUDGET_MIB = 1024
#: The experiment with the largest peak at 10^7 frames (measured with --all on a copy of the tree
#: with the bound raised, 2026-12-02: 947 MiB, the H100/H200 ones 823-899 MiB).
HEAVIEST = ("experiments/sort_last_tc1.toml",)
#: What a run refused by the rule for runs that do not fast-forward prints.
REFUSED = "must fast-forward"


def shipped() -> list[Path]:
    """Every shipped experiment (a TOML file under experiments/ with a [schedule])."""
    return [p for p in sorted((ROOT / "experiments").rglob("*.toml")) if "[schedule]" in p.read_text()]


def measure(experiment: Path, frames: int) -> dict:
    """One `mgpusim simulate` at `frames` frames in a child process: its peak RSS (MiB), wall
    time, exit code, output size and whether it fast-forwarded."""
    out = Path(tempfile.mkdtemp(prefix="mgpusim-mem-"))
    cmd = [sys.executable, "-m", "mgpusim", "simulate", str(experiment), "--set",
           f"schedule.frames={frames}", "--out", str(out / "run")]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = proc.stderr.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    run = out / "run"
    size = sum(f.stat().st_size for f in run.rglob("*") if f.is_file()) if run.is_dir() else 0
    ff = None
    if (run / "summary.json").is_file():
        ff = json.loads((run / "summary.json").read_text()).get("fast_forward", {}).get("used")
    shutil.rmtree(out, ignore_errors=True)
    return {"experiment": str(experiment.relative_to(ROOT)), "frames": frames, "rc": proc.returncode,
            "wall_s": wall, "peak_mib": usage.ru_maxrss / 1024, "output_mib": size / 2**20,
            "fast_forward": ff, "error": err.strip().splitlines()[-1] if proc.returncode else ""}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiments", nargs="*", type=Path, help="experiment files (default: the heaviest)")
    parser.add_argument("--all", action="store_true", help="every shipped experiment")
    parser.add_argument("--frames", type=int, default=MAX_FRAMES, help=f"frames per run (default {MAX_FRAMES:,})")
    args = parser.parse_args()
    paths = shipped() if args.all else [ROOT / p for p in (args.experiments or HEAVIEST)]
    rows = []
    for path in paths:
        r = measure(path.resolve(), args.frames)
        rows.append(r)
        verdict = ("ok" if r["peak_mib"] < BUDGET_MIB else "OVER") if r["rc"] == 0 else \
            "refused" if _refused(r) else f"exit {r['rc']}"
        print(f"{r['experiment']:52s} {r['frames']:>10,} frames  ff={str(r['fast_forward']):5s} "
              f"{r['wall_s']:7.1f} s  peak {r['peak_mib']:7.0f} MiB  out {r['output_mib']:6.0f} MiB  {verdict}"
              + (f"  ({r['error'][:100]})" if r["error"] else ""), flush=True)
    done = [r for r in rows if r["rc"] == 0]
    if done:
        worst = max(done, key=lambda r: r["peak_mib"])
        print(f"largest peak: {worst['peak_mib']:.0f} MiB ({worst['experiment']}, {worst['frames']:,} frames); "
              f"budget {BUDGET_MIB} MiB; every run under it: {all(r['peak_mib'] < BUDGET_MIB for r in done)}")
    return 0 if done and all((r["rc"] == 0 and r["peak_mib"] < BUDGET_MIB) or _refused(r) for r in rows) else 1


def _refused(r: dict) -> bool:
    """A run refused at its start for not fast-forwarding (above MAX_RECORDED_FRAMES frames)."""
    return r["rc"] == 2 and REFUSED in r["error"]


if __name__ == "__main__":
    sys.exit(main())
