"""Speed of the model against raw SimPy on the same machine (`mgpusim bench`).

A "resource use" is one task occupying a queue, copy engine or host thread. Raw SimPy's cost
per use is measured as a process doing request / timeout / release on a Resource.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import simpy

from .experiment import load_experiment
from .simulate import build_program, simulate

DEFAULT_EXPERIMENT = Path(__file__).resolve().parents[1] / "experiments" / "sort_first_tc1.toml"


def raw_simpy_uses_per_s(uses: int = 200_000) -> float:
    env = simpy.Environment()
    res = simpy.Resource(env, capacity=1)

    def worker():
        for _ in range(uses):
            req = res.request()
            yield req
            yield env.timeout(1)
            res.release(req)

    env.process(worker())
    t0 = time.perf_counter()
    env.run()
    return uses / (time.perf_counter() - t0)


def model_speed(experiment: Path, gpus: int, frames: int) -> dict[str, float]:
    exp = load_experiment(experiment, {"schedule.gpus": gpus, "schedule.frames": frames,
                                       "schedule.warmup_frames": 1})
    program = build_program(exp)
    uses_per_frame = sum(_uses(t, exp.profile.host.memcpy_threads) for t in program.tasks(0))
    t0 = time.perf_counter()
    simulate(exp, record_trace=False)
    wall = time.perf_counter() - t0
    return {"frames_per_s": frames / wall, "uses_per_s": frames * uses_per_frame / wall,
            "uses_per_frame": uses_per_frame}


def _uses(task, threads: int) -> int:
    from .tasks import HostCopyTask
    if isinstance(task, HostCopyTask):
        return max(1, min(threads, task.bytes // task.chunk_min_bytes))
    return 1


def run_bench(experiment: Path = DEFAULT_EXPERIMENT, frames: int = 5000) -> dict[str, Any]:
    raw = raw_simpy_uses_per_s()
    out: dict[str, Any] = {"raw_simpy_uses_per_s": raw, "experiment": str(experiment), "frames": frames}
    for gpus in (2, 4):
        try:
            speed = model_speed(experiment, gpus, frames)
        except Exception as exc:  # e.g. the profile has fewer GPUs
            out[f"sort_first_{gpus}gpu"] = {"error": str(exc)}
            continue
        speed["cost_ratio_vs_raw_simpy"] = raw / speed["uses_per_s"]
        out[f"sort_first_{gpus}gpu"] = speed
    return out
