"""Particle sweep of the DX12 thesis (docs/sources.md: particles on a secondary GPU): 256 .. 1M
particles, one vs two GPUs.

For each count it runs experiments/particles_machine.toml (100 frames per point) as
  1gpu       the update on the GTX 1080's compute queue, the draw waits for it;
  2gpu_wait  the update on the HD Graphics 630, the draw waits for its upload;
  2gpu_new   the update on the HD Graphics 630 under "new wait" (skip when busy);
and prints frame time, fps, particle update rate and, per frame that ran them, the times of
the shadow pass, the particle pass and the particle data movement (download start to upload end).

    .venv/bin/python tools/particles_sweep.py [--csv out.csv]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

import mgpusim

COUNTS = (256, 1024, 4096, 16384, 65536, 262144, 524288, 1048576)
CONFIGS = {
    "1gpu": {"schedule.gpus": 1, "schedule.particle_gpu": 0, "schedule.policy": "wait"},
    "2gpu_wait": {"schedule.policy": "wait"},
    "2gpu_new": {"schedule.policy": "new_wait"},
}
EXPERIMENT = Path(__file__).resolve().parents[1] / "experiments" / "particles_machine.toml"


def point(count: int, config: str) -> dict:
    exp = mgpusim.load_experiment(EXPERIMENT, {"schedule.particles": count, **CONFIGS[config]})
    r = mgpusim.simulate(exp)
    s, t = r.summary, r.trace
    steady = t[t.frame >= exp.schedule.warmup_frames]

    def span_ms(mask) -> float:
        """Mean per-frame wall-clock span of the selected tasks, over frames that ran them."""
        g = steady[mask].groupby("frame")
        return float((g.end_ns.max() - g.start_ns.min()).mean() / 1e6) if mask.any() else 0.0

    return {"particles": count, "config": config, "frame_time_ms": round(s["frame_time_ms"], 3),
            "fps": round(s["fps"], 1), "update_hz": round(s["task_rates_hz"]["particle_update"], 1),
            "shadow_ms": round(span_ms(steady.task == "render.shadow"), 3),
            "particle_pass_ms": round(span_ms(steady.step == "particle_update"), 3),
            "data_movement_ms": round(span_ms(steady.task.str.startswith("particles.")), 3),
            "latency_ms": round(s["latency_ms"], 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--csv", help="also write the table here")
    args = ap.parse_args()
    table = pd.DataFrame([point(n, c) for n in COUNTS for c in CONFIGS])
    print(table.to_string(index=False))
    if args.csv:
        table.to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
