"""Simulate every shipped experiment and write their summaries (and a trace digest) as one JSON
file, so that two checkouts can be compared: results must not change when the engine does.

    PYTHONPATH=CHECKOUT python scripts/summaries.py OUT.json [--root CHECKOUT]
        [--fidelity analytic|queues|full] [--no-fast-forward]
    python scripts/summaries.py --compare A.json B.json

An experiment a level refuses (vsync at `analytic`) records the error line instead.
`shipped_experiments` and `simulate_shipped` are the one list of shipped experiments and the one
loop that simulates them; `benchmarks/trace_hashes.py` hashes what they return.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Any, Iterator


def shipped_experiments(root: Path) -> list[Path]:
    """Every TOML file under experiments/ that is an experiment (has a [schedule])."""
    paths = sorted(root.glob("experiments/**/*.toml"))
    return [p for p in paths if "[schedule]" in p.read_text()]


def simulate_shipped(root: Path, fidelity: str = "full", fast_forward: bool = True,
                     overrides: dict | None = None) -> Iterator[tuple[Path, Any]]:
    """(path, result) for every shipped experiment in path order, loaded with `overrides` (dotted
    key -> value); result is the exception instead where loading or simulating fails (a level an
    experiment refuses)."""
    from mgpusim import load_experiment, simulate  # the public API: the same in every layout
    for path in shipped_experiments(root):
        try:
            exp = load_experiment(path, overrides) if overrides else load_experiment(path)
            result = simulate(exp, fidelity=fidelity, fast_forward=fast_forward)
        except Exception as exc:  # noqa: BLE001 (recorded as such by the caller)
            result = exc
        yield path, result


def collect(root: Path, fidelity: str = "full", fast_forward: bool = True) -> dict:
    """Each shipped experiment's summary and the SHA-256 of its trace and frames as CSV."""
    out = {}
    for path, result in simulate_shipped(root, fidelity, fast_forward):
        if isinstance(result, Exception):
            out[str(path.relative_to(root))] = {"summary": {"error": str(result)},
                                                "trace_sha256": "", "frames_sha256": ""}
            continue
        trace = result.trace.to_csv(index=False).encode()
        out[str(path.relative_to(root))] = {
            "summary": json.loads(json.dumps(result.summary, default=str)),
            "trace_sha256": hashlib.sha256(trace).hexdigest(),
            "frames_sha256": hashlib.sha256(result.frames.to_csv(index=False).encode()).hexdigest()}
    return out


def compare(a: dict, b: dict) -> int:
    bad = 0
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b:
            print(f"{name}: only in {'B' if name not in a else 'A'}")
            bad += 1
            continue
        sa, sb = a[name]["summary"], b[name]["summary"]
        changed = sorted(k for k in set(sa) & set(sb) if sa[k] != sb[k])
        added = sorted(set(sb) - set(sa))
        removed = sorted(set(sa) - set(sb))
        same_trace = a[name]["trace_sha256"] == b[name]["trace_sha256"]
        same_frames = a[name]["frames_sha256"] == b[name]["frames_sha256"]
        ok = not changed and not removed and same_trace and same_frames
        bad += not ok
        print(f"{'same' if ok else 'DIFF'} {name}: changed {changed or '-'}, removed {removed or '-'}, "
              f"new keys {added or '-'}, trace {'same' if same_trace else 'DIFF'}, "
              f"frames {'same' if same_frames else 'DIFF'}")
    print(f"{len(set(a) | set(b))} experiments, {bad} differ")
    return 1 if bad else 0


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("out", nargs="?", type=Path)
    p.add_argument("--root", type=Path, default=Path.cwd())
    p.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"))
    p.add_argument("--fidelity", default="full", choices=("analytic", "queues", "full"))
    p.add_argument("--no-fast-forward", dest="fast_forward", action="store_false")
    args = p.parse_args()
    if args.compare:
        return compare(*(json.loads(x.read_text()) for x in args.compare))
    found = collect(args.root.resolve(), args.fidelity, args.fast_forward)
    args.out.write_text(json.dumps(found, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
