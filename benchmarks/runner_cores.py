"""The runner's two cores on one light multi-GPU run: frame time, and each host hand-off split
at the thread that acted on it.

    PYTHONPATH=. python benchmarks/runner_cores.py [--reps 2] [--frames 120] [--devices 0,1,2,3]
        [--set key=value ...] [experiment.toml]

The same experiment runs alternately on the Python executor and the native core
(`run_experiment(runner=...)`), `--reps` times each. Per run it prints the steady frame time
and, over the hand-offs bound by an input (another device's task or a host copy), the mean
wait from the input's end until the thread had seen it (`seen`: the wake), from then to the
submit call (`call`: the thread's own work, and in Python its turn at the interpreter) and to
the task's start (`start`). Default: the lavapipe sort-first experiment on 4 GPUs at 128x96,
light enough that the hand-offs are a large part of a frame; `--devices` puts the simulated GPUs
on real ones.

Measured on four H200s (2026-11-27, the 4x H200 study's light frame at 2560x1440 and 1000
iterations, `mgpusim run`, data/nvidia/h200_x4/native_light_2026-11-27): 3.24-3.30 ms a frame on
the Python executor, 1.89-1.91 ms on the core.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.model.toml_checks import int_list  # noqa: E402
from mgpusim.real.runner.execute import run_experiment  # noqa: E402
from mgpusim.results.waits import host_split  # noqa: E402
from mgpusim.schedules.experiment import load_experiment, parse_overrides  # noqa: E402

DEFAULT = ROOT / "experiments" / "lavapipe" / "sort_first.toml"
LIGHT = ["schedule.gpus=4", "scene.width=128", "scene.height=96", "scene.passes.0.iterations=50"]


def handoffs(trace, submissions, first_frame: int) -> dict[str, float]:
    """Mean seen / call / start of the input-bound hand-offs (ms), weighted by their count."""
    split = host_split(trace, submissions, first_frame)
    n = sum(e["count"] for e in split.values())
    if n == 0:
        return {"seen": 0.0, "call": 0.0, "start": 0.0, "count": 0}
    mean = {key: sum(e[part] * e["count"] for e in split.values()) / n
            for key, part in (("seen", "input_seen_ms"), ("call", "submit_call_ms"),
                              ("start", "device_start_ms"))}
    return {**mean, "count": n}


def measure(exp, runner: str, devices: list[int] | None) -> dict[str, object]:
    """One run of `exp` on `runner`'s core: its frame time and hand-off split."""
    result = run_experiment(exp, devices=devices, runner=runner)
    split = handoffs(result.trace, result.submissions, int(exp.schedule.warmup_frames))
    return {"runner": result.summary["runner"], "frame_ms": result.summary["frame_time_ms"], **split}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("experiment", nargs="?", default=str(DEFAULT))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--devices", help="physical device of each simulated GPU, e.g. 0,1,2,3")
    args = ap.parse_args(argv)
    if args.reps < 1 or args.frames < 10:
        ap.error("--reps must be >= 1 and --frames >= 10")
    sets = (LIGHT if args.experiment == str(DEFAULT) and not args.overrides else []) + args.overrides
    sets += [f"schedule.frames={args.frames}", f"schedule.warmup_frames={args.frames // 5}"]
    exp = load_experiment(args.experiment, parse_overrides(sets))
    devices = int_list(args.devices, "--devices") if args.devices else None
    print(f"{'core':8} {'frame ms':>9} {'seen ms':>8} {'call ms':>8} {'start ms':>9} {'hand-offs':>9}")
    for _rep in range(args.reps):
        for runner in ("python", "native"):
            r = measure(exp, runner, devices)
            print(f"{r['runner']:8} {r['frame_ms']:9.3f} {r['seen']:8.3f} {r['call']:8.3f} "
                  f"{r['start']:9.3f} {r['count']:9d}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
