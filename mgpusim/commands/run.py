"""`mgpusim run EXPERIMENT.toml [--set k=v ...] [--devices I,J,..] [--out DIR]`: the measured run.

Executes the experiment's schedule (the very FrameProgram `simulate` runs) on Vulkan devices and
writes what `mgpusim validate --measured DIR` reads: trace.csv|parquet, frames.csv|parquet,
submissions.csv|parquet (the host side of each GPU task), summary.json (with the config),
machine.json, and image.png (the final displayed frame).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mgpusim.io.out_folder import check_out_dir
from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_RECORDED_FRAMES, MAX_THREADS
from mgpusim.model.toml_checks import int_list


def run(args: argparse.Namespace) -> int:
    from mgpusim.io.shipped import resolve_experiment  # noqa: PLC0415
    from mgpusim.io.writers import write_measured  # noqa: PLC0415
    from mgpusim.schedules.experiment import load_experiment, parse_overrides  # noqa: PLC0415

    exp = load_experiment(resolve_experiment(args.experiment), parse_overrides(args.overrides))
    devices = int_list(args.devices, "--devices")
    if args.gpus_per_device is not None:
        if devices is not None:
            raise InputError("give --devices or --gpus-per-device, not both")
        if args.gpus_per_device < 1:
            raise InputError("must be >= 1", field="--gpus-per-device")
        devices = [i // args.gpus_per_device for i in range(exp.schedule.gpus)]
    _check_counts(args, devices)
    out = args.out or Path("out") / f"{exp.name}-measured"
    check_out_dir(out)
    from mgpusim.real.runner.execute import run_experiment  # noqa: PLC0415 - Vulkan only after the checks
    result = run_experiment(exp, devices=devices, lp_threads=int_list(args.lp_threads, "--lp-threads"),
                            host_threads=args.host_threads, prewarm_frames=args.prewarm)
    write_measured(result, out, args.format)
    _write_png(result.image, out / "image.png")
    s = result.summary
    print(f"{exp.name}: measured {exp.schedule.name} on {exp.schedule.gpus} GPU(s) "
          f"({result.machine['gpus'][0]['device']}), {exp.scene.width}x{exp.scene.height}")
    print(f"  frame time {s['frame_time_ms']:.3f} ms ({s['fps']:.1f} fps), latency "
          f"{s['latency_ms']:.3f} ms, jitter {s['frame_time_jitter_ms']:.3f} ms")
    print("  mean step (ms): " + ", ".join(f"{k} {v:.3f}" for k, v in s["step_mean_ms"].items()))
    for line in s.get("queue_fallbacks", []):
        print(f"  note: {line} (the runner opens one queue of each family the device has and "
              "runs the rest on graphics; `validate` compares the run on the queue it used)")
    print(f"  wrote {out}")
    return 0


def _check_counts(args: argparse.Namespace, devices: list[int] | None) -> None:
    """Thread counts, devices and pre-warm frames in range, before any device is opened."""
    if devices is not None and min(devices) < 0:
        raise InputError(f"device indices must be >= 0, got {args.devices}", field="--devices")
    lp = int_list(args.lp_threads, "--lp-threads") or []
    if lp and not all(1 <= n <= MAX_THREADS for n in lp):
        raise InputError(f"must be in 1..{MAX_THREADS}, got {args.lp_threads}", field="--lp-threads")
    if args.host_threads is not None and not 1 <= args.host_threads <= MAX_THREADS:
        raise InputError(f"must be in 1..{MAX_THREADS}, got {args.host_threads}", field="--host-threads")
    if args.prewarm is not None and not 0 <= args.prewarm <= MAX_RECORDED_FRAMES:
        raise InputError(f"must be in 0..{MAX_RECORDED_FRAMES}, got {args.prewarm}", field="--prewarm")


def _write_png(image, path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    plt.imsave(path, image)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("run", help="run an experiment's schedule on Vulkan devices (measured)",
                              description=__doc__)
    p.add_argument("experiment", type=Path, help="experiment TOML file, or a shipped name (`mgpusim examples`)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="override a field, e.g. schedule.gpus=2 (repeatable)")
    p.add_argument("--devices", metavar="I,J,...",
                   help="physical device of each simulated GPU (default: GPU i on device i mod count)")
    p.add_argument("--gpus-per-device", type=int, metavar="K",
                   help="put K simulated GPUs on each physical device (GPU i on device i // K)")
    p.add_argument("--lp-threads", metavar="N[,N...]",
                   help="lavapipe LP_NUM_THREADS per simulated GPU (one value: all)")
    p.add_argument("--host-threads", type=int, help="memcpy threads (default: the profile's)")
    p.add_argument("--prewarm", type=int, help="untimed frames before the run (default: max(2, "
                   "buffers, frame phases), rounded up to whole frame phases)")
    p.add_argument("--out", type=Path, help="output folder (default: out/<experiment>-measured)")
    p.add_argument("--format", choices=("csv", "parquet"), default="csv", help="table format")
    p.set_defaults(func=run)
