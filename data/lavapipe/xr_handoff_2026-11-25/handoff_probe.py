"""Where XR's frame-to-frame hand-off loses time on lavapipe: one instrumented run per scaling.

Runs `experiments/lavapipe/xr.toml` (2 GPUs, 8 rasterizer threads each) under strong and weak
scaling with `Gpu.submit` and `Submission.finished` wrapped to log the host clock, then splits
the wait from the producer's end (GPU 0's render under strong scaling, its present under weak)
to GPU 1's next render into: GPU 1's submit thread sees the fence, calls vkQueueSubmit, the
render starts. It also splits the fence wake by whether GPU 0's own submit thread was inside a
submit when the producer ended.

    .venv/bin/python data/lavapipe/xr_handoff_2026-11-25/handoff_probe.py OUT_DIR [FRAMES]

A record of one experiment, not part of the package: it patches the runner from outside.
"""
from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd

import mgpusim.real.vulkan.device as device
from mgpusim.cli import main

LOG: list[tuple] = []
_LOCK = threading.Lock()
_SUBMIT, _FINISHED = device.Gpu.submit, device.Submission.finished


def _submit(self, queue, record, *, wait=(), signal=(), label="", key=None):
    t0 = time.monotonic_ns()
    out = _SUBMIT(self, queue, record, wait=wait, signal=signal, label=label, key=key)
    with _LOCK:
        LOG.append(("submit", label, t0, time.monotonic_ns(), threading.current_thread().name))
    return out


def _finished(self, timeout_ns):
    before = self._finished
    done = _FINISHED(self, timeout_ns)
    if done and not before:
        with _LOCK:
            LOG.append(("seen", self.label, time.monotonic_ns(), 0, threading.current_thread().name))
    return done


def split(run: Path, log: list[tuple], producer: str) -> pd.DataFrame:
    """Per frame f: GPU 0's `producer` of f -> GPU 1's render of f + 1, in us from the producer's
    end, and whether GPU 0's submit thread was inside a submit at that end."""
    origin = json.loads((run / "summary.json").read_text())["clock_origin_ns"]
    trace = pd.read_csv(run / "trace.csv")
    at = {(int(f), t): (s + origin, e + origin) for f, t, s, e in
          zip(trace["frame"], trace["task"], trace["start_ns"], trace["end_ns"])}
    submits = {lab: (a, b) for kind, lab, a, b, _ in log if kind == "submit"}
    gpu0 = [(a, b) for kind, _, a, b, who in log if kind == "submit" and who == "submit-gpu0/0"]
    seen = {lab: a for kind, lab, a, _, _ in log if kind == "seen"}
    rows = []
    for f in sorted({f for f, _ in at}):
        src, dst = (f, producer), (f + 1, "render1.tori")
        label = f"frame {f} {producer}"
        if src not in at or dst not in at or label not in seen:
            continue
        end = at[src][1]
        call, ret = submits[f"frame {f + 1} render1.tori"]
        rows.append({"frame": f, "fence_seen_us": (seen[label] - end) / 1e3,
                     "submit_call_us": (call - end) / 1e3, "render_start_us": (at[dst][0] - end) / 1e3,
                     "gpu0_in_submit": any(a <= end <= b for a, b in gpu0)})
    return pd.DataFrame(rows)


def probe(out: Path, scaling: str, producer: str, frames: int) -> pd.DataFrame:
    LOG.clear()
    run = out / scaling
    main(["run", "experiments/lavapipe/xr.toml", "--set", f"schedule.scaling={scaling}",
          "--set", f"schedule.frames={frames}", "--lp-threads", "8", "--out", str(run)])
    table = split(run, list(LOG), producer)
    table.insert(0, "scaling", scaling)
    return table


if __name__ == "__main__":
    device.Gpu.submit, device.Submission.finished = _submit, _finished
    out = Path(sys.argv[1])
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 60
    table = pd.concat([probe(out, "strong", "render0.tori", frames),
                       probe(out, "weak", "present", frames)])
    table.to_csv(out / "handoffs.csv", index=False)
    cols = ["fence_seen_us", "submit_call_us", "render_start_us"]
    print(table.groupby("scaling")[cols].median().round(0).to_string())
    print(table.groupby(["scaling", "gpu0_in_submit"])["fence_seen_us"]
          .agg(["count", "median"]).round(0).to_string())
    print("probe:", np.round(table[cols].median().to_numpy(), 0))
