"""Print one hash per shipped experiment of what the event engine simulates, so that a change
meant to be a pure speed-up can be checked to change no result: run it before and after, and
diff the outputs (every line must match).

Each experiments/**/*.toml that loads is simulated at `full` fidelity for `--frames` frames with
the fast-forward off (every frame through the event engine; `--fast-forward` turns it on), and
its trace, frames and links tables and its summary are hashed together. An experiment that
fails to load or simulate prints its error's type instead of a hash (the same before and after).
Last come the two configurations `mgpusim bench --what simpy` times (TC1 sort-first at 2 and 4
GPUs, one warm-up frame).

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

from mgpusim import Experiment, load_experiment, simulate  # noqa: E402
from mgpusim.studies.model_speed import DEFAULT_EXPERIMENT, sort_first_experiment  # noqa: E402


def table_digest(table: pd.DataFrame) -> bytes:
    """The table's values row by row, its column names and its index (pandas' own hash)."""
    values = pd.util.hash_pandas_object(table, index=True).to_numpy().tobytes()
    return values + repr(list(table.columns)).encode()


def run_digest(exp: Experiment, fast_forward: bool) -> str:
    """The hash of one experiment's simulated tables and summary."""
    result = simulate(exp, fidelity="full", fast_forward=fast_forward)
    digest = hashlib.sha256()
    for table in (result.trace, result.frames, result.links):
        digest.update(table_digest(table))
    digest.update(json.dumps(result.summary, sort_keys=True, default=repr).encode())
    return f"{digest.hexdigest()[:16]} rows={len(result.trace)}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=200, help="frames per experiment (default: 200)")
    p.add_argument("--fast-forward", action="store_true", help="with the fast-forward on")
    args = p.parse_args()
    for path in sorted(ROOT.glob("experiments/**/*.toml")):
        name = str(path.relative_to(ROOT / "experiments"))
        try:
            line = run_digest(load_experiment(path, {"schedule.frames": args.frames}), args.fast_forward)
        except Exception as exc:  # noqa: BLE001 (not an experiment, or one this setting refuses)
            line = f"skipped ({type(exc).__name__})"
        print(f"{name} {line}", flush=True)
    for gpus in (2, 4):
        exp = sort_first_experiment(DEFAULT_EXPERIMENT, gpus, args.frames)
        print(f"bench sort_first_{gpus}gpu {run_digest(exp, args.fast_forward)}", flush=True)


if __name__ == "__main__":
    main()
