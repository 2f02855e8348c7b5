"""Speed of the model against raw SimPy on the same machine (`mgpusim bench`).

A "resource use" is one occupation of a modelled resource: a task on a queue or copy engine,
a host-copy part on a memcpy thread, and a transfer on a link direction or on host memory
bandwidth (a copy uses its queue and its link: two uses). The per-task figure, which counts a
copy once, is reported beside it. Raw SimPy's cost per use is measured as a process doing
request / timeout / release on a Resource.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import simpy

from .experiment import load_experiment
from .shipped import shipped_dir
from .simulate import build_program, simulate
from .tasks import CopyTask, HostCopyTask

DEFAULT_EXPERIMENT = shipped_dir("experiments") / "sort_first_tc1.toml"


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
    base = load_experiment(experiment).profile
    if gpus > len(base.gpus):  # a what-if: more GPUs like the profile's last one
        base = replace(base, gpus=base.gpus + (base.gpus[-1],) * (gpus - len(base.gpus)))
    exp = load_experiment(experiment, {"schedule.gpus": gpus, "schedule.frames": frames,
                                       "schedule.warmup_frames": 1}, profile=base)
    program = build_program(exp)
    tasks = program.tasks(0)
    threads = exp.profile.host.memcpy_threads
    parts = sum(t.parts(threads) for t in tasks if isinstance(t, HostCopyTask))
    task_uses = sum(1 for t in tasks if not isinstance(t, HostCopyTask)) + parts
    link_uses = sum(1 for t in tasks if isinstance(t, CopyTask)) + parts
    t0 = time.perf_counter()
    simulate(exp, record_trace=False)
    wall = time.perf_counter() - t0
    uses = task_uses + link_uses
    return {"frames_per_s": frames / wall, "uses_per_s": frames * uses / wall, "uses_per_frame": uses,
            "task_uses_per_frame": task_uses, "link_uses_per_frame": link_uses,
            "task_uses_per_s": frames * task_uses / wall}


def run_bench(experiment: Path = DEFAULT_EXPERIMENT, frames: int = 5000, repeats: int = 3) -> dict[str, Any]:
    """Best of `repeats` interleaved runs of each figure, so that a busy machine (other
    processes on the same cores) distorts the ratio as little as possible."""
    raw = 0.0
    best: dict[int, dict[str, float]] = {}
    for _ in range(repeats):
        raw = max(raw, raw_simpy_uses_per_s())
        for gpus in (2, 4):
            speed = model_speed(experiment, gpus, frames)
            if gpus not in best or speed["uses_per_s"] > best[gpus]["uses_per_s"]:
                best[gpus] = speed
    out: dict[str, Any] = {"raw_simpy_uses_per_s": raw, "experiment": str(experiment), "frames": frames,
                           "repeats": repeats}
    for gpus, speed in best.items():
        speed["cost_ratio_vs_raw_simpy"] = raw / speed["uses_per_s"]
        speed["cost_ratio_per_task_vs_raw_simpy"] = raw / speed["task_uses_per_s"]
        out[f"sort_first_{gpus}gpu"] = speed
    return out
