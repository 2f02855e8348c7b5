"""How long `mgpusim frame import` takes, and how much memory, on a large Chrome trace (target:
10^6 events in under 30 s and 1 GiB of peak RSS on 2 cores).

    PYTHONPATH=. python benchmarks/frame_import_size.py [--events 1000000] [--passes 100]
    PYTHONPATH=. python benchmarks/frame_import_size.py --events 100000 --passes 100000

Why a generated trace: a profiler capture of a few seconds of a game is 10^5 to 10^6 GPU
slices, and a capture of one frame of an engine that names every draw is 10^5 distinct pass
names: the first is where per-event cost shows, the second where per-pass cost does. The trace
is `frames` frames of `passes` complete events each on one graphics queue, inside a `Frame k`
group, every pass reading the one before it (so reads are resolved), with a CPU thread. The
import runs in a child process so that the peak RSS printed is the import's alone (the parent
built the trace); wall time is the child's, start-up included.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def write_trace(path: Path, events: int, passes: int) -> int:
    """A Chrome trace of about `events` GPU slices, `passes` distinct names a frame; returns
    the number of frames. Written event by event (a list of 10^6 dicts would be the parent's
    memory, not the import's)."""
    frames = max(1, events // passes)
    with path.open("w", encoding="utf-8") as f:
        f.write('{"metadata": {"width": 1920, "height": 1080}, "traceEvents": [\n')
        f.write(json.dumps({"ph": "M", "name": "process_name", "pid": 1, "tid": 0, "args": {"name": "GPU"}}))
        f.write(",\n" + json.dumps({"ph": "M", "name": "thread_name", "pid": 1, "tid": 1,
                                    "args": {"name": "Graphics queue"}}))
        f.write(",\n" + json.dumps({"ph": "M", "name": "thread_name", "pid": 2, "tid": 7,
                                    "args": {"name": "main"}}))
        t = 0.0
        for frame in range(frames):
            f.write(",\n" + json.dumps({"ph": "X", "name": f"Frame {frame}", "pid": 1, "tid": 1, "ts": t,
                                        "dur": passes * 10.0}))
            f.write(",\n" + json.dumps({"ph": "X", "name": "update", "pid": 2, "tid": 7, "ts": t, "dur": 3.0}))
            for p in range(passes):
                ev = {"ph": "X", "name": f"pass{p}", "pid": 1, "tid": 1, "ts": t + p * 10.0,
                      "dur": 5.0 + (p + frame) % 7, "args": {"writes": [f"r{p}"],
                                                           "reads": [f"r{p - 1}"] if p else []}}
                f.write(",\n" + json.dumps(ev))
            t += passes * 10.0 + 100.0
        f.write("\n]}\n")
    return frames


def import_in_child(trace: Path, out: Path) -> tuple[float, int, int]:
    """(wall s, peak RSS in bytes, exit code) of `mgpusim frame import` in a fresh process."""
    start = time.perf_counter()
    code = subprocess.run([sys.executable, "-m", "mgpusim", "frame", "import", str(trace), "--out", str(out)],
                          cwd=ROOT, stdout=subprocess.DEVNULL).returncode
    wall = time.perf_counter() - start
    return wall, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024, code


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--events", type=int, default=1_000_000, help="GPU slices in the trace")
    ap.add_argument("--passes", type=int, default=100, help="distinct pass names a frame")
    ap.add_argument("--keep", type=Path, default=None, help="write the trace and experiment here, and keep them")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        trace = folder / "big.json"
        frames = write_trace(trace, args.events, args.passes)
        size = trace.stat().st_size
        wall, rss, code = import_in_child(trace, folder / "big.toml")
    with open("/proc/loadavg", encoding="ascii") as f:
        load = f.read().split()[0]
    print(f"{frames * args.passes} events ({frames} frames x {args.passes} passes, {size / 2**20:.0f} MiB): "
          f"import {wall:.1f} s, peak RSS {rss / 2**20:.0f} MiB, exit {code} (load {load})")
    return code


if __name__ == "__main__":
    sys.exit(main())
