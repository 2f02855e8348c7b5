"""Print one hash per shipped experiment of what the event engine simulates, so that a change
meant to be a pure speed-up can be checked to change no result: run it before and after, and
diff the outputs (every line must match).

Each shipped experiment (`shipped_experiments` in scripts/summaries.py: experiments/**/*.toml
with a [schedule]; `simulate_shipped` there loads and simulates them) is simulated at `full`
fidelity for `--frames` frames with the fast-forward off (every frame through the event engine;
`--fast-forward` turns it on), and its trace, frames and links tables and its summary are hashed
together. One line each, `NAME HASH rows=TRACE_ROWS` (NAME relative to experiments/); one that
fails to load or simulate prints `NAME skipped (ERROR_TYPE)` instead (the same before and after).
Last come the two configurations `mgpusim bench --what simpy` times (TC1 sort-first at 2 and 4
GPUs, one warm-up frame), named `bench sort_first_2gpu` and `bench sort_first_4gpu`.
Since 2026-11-27 TOML files under experiments/ that are not experiments (case, machine, study
files) print no line (they printed `skipped (InputError)` before); every hash is the same.

    PYTHONPATH=. python benchmarks/trace_hashes.py [--frames 200] [--fast-forward] > hashes.txt
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim import Experiment, Result, simulate  # noqa: E402
from mgpusim.bench.model_speed import DEFAULT_EXPERIMENT, sort_first_experiment  # noqa: E402
from scripts.summaries import simulate_shipped  # noqa: E402


def table_digest(table: pd.DataFrame) -> bytes:
    """The table's values row by row, its column names and its index (pandas' own hash)."""
    values = pd.util.hash_pandas_object(table, index=True).to_numpy().tobytes()
    return values + repr(list(table.columns)).encode()


def result_digest(result: Result) -> str:
    """The hash of one simulation's trace, frames and links tables and summary."""
    digest = hashlib.sha256()
    for table in (result.trace, result.frames, result.links):
        digest.update(table_digest(table))
    digest.update(json.dumps(result.summary, sort_keys=True, default=repr).encode())
    return f"{digest.hexdigest()[:16]} rows={len(result.trace)}"


def run_digest(exp: Experiment, fast_forward: bool) -> str:
    """The hash of one experiment simulated at `full` fidelity."""
    return result_digest(simulate(exp, fidelity="full", fast_forward=fast_forward))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=200, help="frames per experiment (default: 200)")
    p.add_argument("--fast-forward", action="store_true", help="with the fast-forward on")
    args = p.parse_args()
    shipped = simulate_shipped(ROOT, "full", args.fast_forward, {"schedule.frames": args.frames})
    for path, result in shipped:
        name = str(path.relative_to(ROOT / "experiments"))
        failed = isinstance(result, Exception)
        line = f"skipped ({type(result).__name__})" if failed else result_digest(result)
        print(f"{name} {line}", flush=True)
    for gpus in (2, 4):
        exp = sort_first_experiment(DEFAULT_EXPERIMENT, gpus, args.frames)
        print(f"bench sort_first_{gpus}gpu {run_digest(exp, args.fast_forward)}", flush=True)


if __name__ == "__main__":
    main()
