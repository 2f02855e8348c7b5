"""Time the Perfetto export (and the timeline PNG) on a long run: the default window of
frames against the whole run.

    PYTHONPATH=. python benchmarks/export_speed.py [FRAMES]
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import mgpusim
from mgpusim.io.defaults import TRACE_FRAMES
from mgpusim.io.perfetto import chrome_trace_json
from mgpusim.io.plot import timeline_png
from mgpusim.io.writers import frame_window

ROOT = Path(__file__).resolve().parents[1]


def main(frames: int = 2000) -> None:
    exp = mgpusim.load_experiment(ROOT / "experiments" / "particles_machine.toml", {"schedule.frames": frames})
    result = mgpusim.simulate(exp)
    print(f"particles_machine, {frames} frames: {len(result.trace)} trace rows, {len(result.links)} link intervals")
    for label, last in ((f"last {TRACE_FRAMES} frames (default)", TRACE_FRAMES), ("whole run", 0)):
        trace, links = frame_window(result.trace, result.links, last=last)
        t0 = time.perf_counter()
        text = chrome_trace_json(trace, links, "bench")
        dt = time.perf_counter() - t0
        print(f"  perfetto, {label}: {len(trace)} rows -> {len(text) / 1e6:.1f} MB in {dt:.2f} s "
              f"({len(trace) / dt:,.0f} rows/s)")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        timeline_png(result.trace, Path(tmp) / "t.png", result.links, "bench")
        print(f"  timeline.png (last 4 frames): {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)
