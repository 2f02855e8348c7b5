"""Regenerate the timeline pictures of docs/schedules/*.md from the shipped experiments.

    .venv/bin/python docs/schedules/make_images.py
"""
from __future__ import annotations

from pathlib import Path

import mgpusim
from mgpusim.io.plot import timeline_png

ROOT = Path(__file__).resolve().parents[2]
IMG = Path(__file__).with_name("img")

PICTURES = {
    "afr_tc1": ("afr_tc1.toml", {}),
    "afr_temporal_tc1": ("afr_temporal_tc1.toml", {}),
    "pipelining_miniengine": ("pipelining_miniengine_pcie3x8.toml", {}),
    "pipelining_miniengine_no_copy_engine": ("pipelining_miniengine_pcie3x8.toml", {"schedule.copy_queue": "graphics"}),
    "xr_quest3_pcie4_weak": ("xr_quest3_pcie4.toml", {}),
    "xr_quest3_pcie4_strong": ("xr_quest3_pcie4.toml", {"schedule.scaling": "strong"}),
    "particles_1m_new_wait": ("particles_machine.toml", {"schedule.particles": 1048576}, range(20, 31)),
    "particles_1m_wait": ("particles_machine.toml", {"schedule.particles": 1048576, "schedule.policy": "wait"}),
}


def main() -> None:
    IMG.mkdir(exist_ok=True)
    for name, (file, overrides, *frames) in PICTURES.items():
        exp = mgpusim.load_experiment(ROOT / "experiments" / file, overrides)
        r = mgpusim.simulate(exp)
        s = r.summary
        title = (f"{name}: frame time {s['frame_time_ms']:.2f} ms, latency {s['latency_ms']:.2f} ms")
        timeline_png(r.trace, IMG / f"{name}.png", r.links, title=title,
                     frames=list(frames[0]) if frames else None)
        print(f"{name}: {title}")


if __name__ == "__main__":
    main()
