"""Speed of the model against raw SimPy on the same machine (`mgpusim bench`).

Two comparisons, both with the fast-forward off (every frame simulated):

- Per simulated frame, against a hand-written SimPy model of the same sort-first frame
  (:func:`mgpusim.bench.reference.hand_written_sort_first`): render on every GPU, each secondary's download, host copy
  over the memcpy threads and upload, composite and present, with the same buffers and frames
  in flight. It reproduces the model's presents exactly (a test checks it), so both compute
  the same thing: a frame's cost is what a user would otherwise pay.
- Per event and per "resource use", against raw SimPy. A resource use is one occupation of a
  modelled resource: a task on a queue or copy engine, a host-copy part on a memcpy thread,
  and a transfer on a link direction or on host memory bandwidth (a copy uses its queue and
  its link: two uses); the per-task figure counts a copy once. Raw SimPy's cost per use is a
  process doing request / timeout / release on a Resource. Events are SimPy events scheduled
  per simulated frame, counted in a separate run of each model.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import simpy
from simpy.core import SimTime
from simpy.events import EventPriority

from mgpusim.bench.reference import hand_written_sort_first, raw_simpy_uses_per_s
from mgpusim.io.shipped import shipped_dir
from mgpusim.model.costs import CostModel
from mgpusim.model.tasks import CopyTask, HostCopyTask
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim.analytic_lanes import sweep
from mgpusim.sim.effects import EFFECTS, choose_effects
from mgpusim.sim.engine import Engine
from mgpusim.sim.simulation import simulate

DEFAULT_EXPERIMENT = shipped_dir("experiments") / "sort_first_tc1.toml"
#: A fresh interpreter that simulates a long run and prints wall time and peak memory (a child
#: process, so that the peak is the run's own and not the benchmark's).
_LONG_RUN = """
import json, resource, sys, tempfile, time
from pathlib import Path
t0 = time.perf_counter()
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate
t1 = time.perf_counter()
exp = load_experiment(sys.argv[1], {"schedule.frames": int(sys.argv[2])})
result = simulate(exp, fidelity=sys.argv[3])
t2 = time.perf_counter()
out = {"simulate_s": t2 - t1, "process_s": t2 - t0, "frames": len(result.frames),
       "frame_time_ms": result.summary["frame_time_ms"], "fast_forward": result.summary["fast_forward"],
       "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
from mgpusim.io.writers import write_links, write_table, write_trace  # after the peak above: it loads matplotlib
with tempfile.TemporaryDirectory() as tmp:
    write_trace(result, Path(tmp) / "trace.parquet")
    write_table(result.frames, Path(tmp) / "frames.parquet")
    write_links(result, Path(tmp) / "links.parquet")
    out["trace_mb"] = (Path(tmp) / "trace.parquet").stat().st_size / 2**20
out.update(write_s=time.perf_counter() - t2, rows=len(result.repeated) if result.compact else len(result.trace),
           peak_rss_with_tables_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
print(json.dumps(out))
"""


def sort_first_experiment(experiment: Path, gpus: int, frames: int) -> Any:
    """The experiment at `gpus` GPUs (the profile's last GPU repeated where it has fewer) and
    `frames` frames, one warm-up frame."""
    base = load_experiment(experiment).profile
    if gpus > len(base.gpus):  # a what-if: more GPUs like the profile's last one
        base = replace(base, gpus=base.gpus + (base.gpus[-1],) * (gpus - len(base.gpus)))
    return load_experiment(experiment, {"schedule.gpus": gpus, "schedule.frames": frames,
                                        "schedule.warmup_frames": 1}, profile=base)


class _Counting(simpy.Environment):
    """An environment that counts the events scheduled on it."""

    def __init__(self) -> None:
        super().__init__()
        self.events = 0

    def schedule(self, event: simpy.Event, priority: EventPriority = simpy.events.NORMAL,
                 delay: SimTime = 0) -> None:
        self.events += 1
        super().schedule(event, priority, delay)


def events_per_frame(exp: Any, frames: int) -> dict[str, float]:
    """SimPy events scheduled per simulated frame by the model (fast-forward off) and by the
    hand-written model, each in a counting run of `frames` frames."""
    engine = Engine(build_program(replace(exp, schedule=replace(exp.schedule, frames=frames))),
                    CostModel(exp.profile), record_trace=False)
    engine.env.stop_tracking()
    count = [0]
    plain = engine.env.schedule

    def counted(event: simpy.Event, priority: EventPriority = simpy.events.NORMAL, delay: SimTime = 0) -> None:
        count[0] += 1
        plain(event, priority, delay)
    engine.env.schedule = counted  # type: ignore[method-assign]  # counted on this one instance
    engine.run()
    env = _Counting()
    hand_written_sort_first(exp, frames, env)
    return {"model": count[0] / frames, "hand_written": env.events / frames}


def model_speed(experiment: Path, gpus: int, frames: int) -> dict[str, float]:
    exp = sort_first_experiment(experiment, gpus, frames)
    program = build_program(exp)
    tasks = program.tasks(0)
    threads = exp.profile.host.memcpy_threads
    parts = sum(t.parts(threads) for t in tasks if isinstance(t, HostCopyTask))
    task_uses = sum(1 for t in tasks if not isinstance(t, HostCopyTask)) + parts
    link_uses = sum(1 for t in tasks if isinstance(t, CopyTask)) + parts
    t0 = time.perf_counter()
    simulate(exp, record_trace=False, fast_forward=False)  # every frame simulated: the per-use cost
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    hand_written_sort_first(exp)
    hand = time.perf_counter() - t0
    uses = task_uses + link_uses
    return {"frames_per_s": frames / wall, "uses_per_s": frames * uses / wall, "uses_per_frame": uses,
            "task_uses_per_frame": task_uses, "link_uses_per_frame": link_uses,
            "task_uses_per_s": frames * task_uses / wall, "hand_written_frames_per_s": frames / hand}


def run_bench(experiment: Path = DEFAULT_EXPERIMENT, frames: int = 5000, repeats: int = 3,
              progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Best of `repeats` interleaved runs of each figure, so that a busy machine (other
    processes on the same cores) distorts the ratio as little as possible. `progress(step)`:
    called before each of the 2 x `repeats` + 2 steps."""
    say = progress or (lambda _step: None)
    raw = 0.0
    best: dict[int, dict[str, float]] = {}
    for rep in range(repeats):
        raw = max(raw, raw_simpy_uses_per_s())
        for gpus in (2, 4):
            say(f"{gpus} GPUs, run {rep + 1} of {repeats}")
            speed = model_speed(experiment, gpus, frames)
            if gpus not in best or speed["uses_per_s"] > best[gpus]["uses_per_s"]:
                best[gpus] = speed
    counting = _Counting()
    raw_simpy_uses_per_s(1000, counting)
    out: dict[str, Any] = {"raw_simpy_uses_per_s": raw, "raw_simpy_events_per_use": counting.events / 1000,
                           "raw_simpy_events_per_s": raw * counting.events / 1000,
                           "experiment": str(experiment), "frames": frames, "repeats": repeats}
    for gpus, speed in best.items():
        speed["cost_ratio_vs_raw_simpy"] = raw / speed["uses_per_s"]
        speed["cost_ratio_per_task_vs_raw_simpy"] = raw / speed["task_uses_per_s"]
        say(f"{gpus} GPUs, events counted")
        events = events_per_frame(sort_first_experiment(experiment, gpus, frames), min(frames, 1000))
        speed["events_per_frame"] = events["model"]
        speed["hand_written_events_per_frame"] = events["hand_written"]
        speed["events_per_s"] = speed["frames_per_s"] * events["model"]
        speed["hand_written_events_per_s"] = speed["hand_written_frames_per_s"] * events["hand_written"]
        speed["speedup_per_frame_vs_hand_written"] = speed["frames_per_s"] / speed["hand_written_frames_per_s"]
        speed["event_cost_vs_hand_written"] = speed["hand_written_events_per_s"] / speed["events_per_s"]
        speed["event_cost_vs_raw_simpy"] = out["raw_simpy_events_per_s"] / speed["events_per_s"]
        out[f"sort_first_{gpus}gpu"] = speed
    return out


def long_run(experiment: Path = DEFAULT_EXPERIMENT, frames: int = 1_000_000, fidelity: str = "full") -> dict[str, Any]:
    """Wall time and peak memory of one long run in a fresh process (fast-forward on), then of
    streaming its whole trace, frames and links tables to Parquet."""
    out = subprocess.run([sys.executable, "-c", _LONG_RUN, str(experiment), str(frames), fidelity],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)  # text, not a file: the child's printed result


def analytic_speed(experiment: Path = DEFAULT_EXPERIMENT, configurations: int = 100_000) -> dict[str, Any]:
    """Configurations per second of the analytic level: a sweep of `configurations` hardware
    variants (pass and transfer times scaled 0.25x-4x) of one experiment, and one-at-a-time
    `simulate(fidelity="analytic")` for comparison."""
    import numpy as np  # noqa: PLC0415
    exp = load_experiment(experiment)
    program, costs = build_program(exp), CostModel(exp.profile)
    rng = np.random.default_rng(0)
    scales = rng.uniform(0.25, 4.0, (2, configurations))
    t0 = time.perf_counter()
    sweep(program, costs, scales[0], scales[1])
    swept = time.perf_counter() - t0
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < 1.0:
        simulate(exp, fidelity="analytic", record_trace=False)
        n += 1
    single = n / (time.perf_counter() - t0)
    return {"sweep_configurations": configurations, "sweep_s": swept,
            "sweep_configurations_per_s": configurations / swept, "simulate_analytic_per_s": single}


def effects_saving(experiment: Path = DEFAULT_EXPERIMENT, frames: int = 3000, repeats: int = 3) -> dict[str, Any]:
    """Time of a run with only the effects its scene needs, against the same run with every
    unneeded effect forced on (same trace: tests check it), fast-forward off. Best of `repeats`."""
    exp = load_experiment(experiment, {"schedule.frames": frames})
    needed = choose_effects(build_program(exp), exp.profile)
    forced = {n: True for n, e in EFFECTS.items() if n not in needed and e.forceable}
    best = {"needed": float("inf"), "forced": float("inf")}
    for _ in range(repeats):
        for key, effects in (("needed", None), ("forced", forced)):
            t0 = time.perf_counter()
            simulate(exp, record_trace=False, effects=effects, fast_forward=False)
            best[key] = min(best[key], time.perf_counter() - t0)
    return {"experiment": str(experiment), "frames": frames, "needed": sorted(needed), "forced_on": sorted(forced),
            "needed_s": best["needed"], "forced_s": best["forced"], "saved": 1 - best["needed"] / best["forced"]}


LAVAPIPE_EXPERIMENT = DEFAULT_EXPERIMENT.parent / "lavapipe" / "sort_first.toml"


def effect_costs(experiment: Path = LAVAPIPE_EXPERIMENT, frames: int = 3000, repeats: int = 3) -> dict[str, Any]:
    """What each effect a scene needs costs in time: the run with all of them, and with each one
    forced off (a different, less accurate model), fast-forward off. Best of `repeats`."""
    exp = load_experiment(experiment, {"schedule.frames": frames})
    needed = sorted(n for n in choose_effects(build_program(exp), exp.profile) if n != "memory_capacity")
    runs: dict[str, float] = {}
    for _ in range(repeats):
        for name in ["all", *needed]:
            t0 = time.perf_counter()
            simulate(exp, record_trace=False, effects=None if name == "all" else {name: False}, fast_forward=False)
            runs[name] = min(runs.get(name, float("inf")), time.perf_counter() - t0)
    return {"experiment": str(experiment), "frames": frames, "all_s": runs["all"],
            "without_s": {n: runs[n] for n in needed}}
