"""`python -m mgpusim.vmgpu --build DIR --out DIR`: measure an already-built vmgpu (on lavapipe
unless `--driver native`) over a grid of strategy x GPUs x triangles x resolution, and write the
tables.

Why a command of its own: the measurement runs for half an hour on a shared machine and must be
repeatable from one line; PROVENANCE.md records that line.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import pandas as pd

from mgpusim.vmgpu import campaign, provenance, tables
from mgpusim.vmgpu.build_folder import check_build
from mgpusim.vmgpu.display import Xvfb
from mgpusim.vmgpu.failures import VmgpuMeasureError
from mgpusim.vmgpu.launch import DRIVERS, STRATEGIES
from mgpusim.vmgpu.speed import NoProbe, ProjectProbe


def resolution(value: str) -> tuple[int, int]:
    """'640x480' -> (640, 480)."""
    try:
        width, height = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT such as 640x480, got {value!r}") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"a resolution of 16-8192 pixels a side, got {value!r}")
    return width, height


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mgpusim.vmgpu",
        description="Measure an already-built vmgpu (patched with the VMGPU_FRAME_LOG measuring "
                    "aid) under Xvfb, on lavapipe or the machine's own Vulkan driver; write "
                    "runs.parquet, frames.parquet and PROVENANCE.md to --out once every run has "
                    "finished.")
    p.add_argument("--build", type=Path, required=True, help="vmgpu's build folder (holds the "
                   "vmgpu executable and spv/)")
    p.add_argument("--out", type=Path, required=True, help="output folder (must not hold a "
                   "measurement yet)")
    p.add_argument("--strategies", nargs="+", choices=STRATEGIES, default=list(STRATEGIES))
    p.add_argument("--gpus", nargs="+", type=int, default=[1, 2, 3, 4],
                   help="simulated GPU counts (single runs on 1; sort-first/-last on 2 or more)")
    p.add_argument("--triangles", nargs="+", type=int, default=[100_000, 1_000_000],
                   help="sphere triangle counts (10000-5000000)")
    p.add_argument("--resolutions", nargs="+", type=resolution,
                   default=[(640, 480), (1024, 768)], help="window sizes, WIDTHxHEIGHT")
    p.add_argument("--frames", type=int, default=200, help="frames per run (default 200)")
    p.add_argument("--warmup", type=int, default=20,
                   help="first frames of each run left out of its statistics (default 20)")
    p.add_argument("--repeats", type=int, default=3, help="runs per configuration, interleaved")
    p.add_argument("--patch", type=Path, help="the patch file the build carries (its sha256 goes "
                   "into PROVENANCE.md)")
    p.add_argument("--stall-factor", type=float, default=5.0,
                   help="a frame over this many times its run's median is a stall")
    p.add_argument("--run-timeout", type=float, default=300.0, help="seconds per run at most")
    p.add_argument("--seed", type=int, default=0, help="seed of each round's shuffled order")
    p.add_argument("--mesh-dir", type=Path, help="where the sphere OBJs are kept (default: a "
                   "temporary folder)")
    p.add_argument("--keep-logs", type=Path, help="also keep each run's raw output here")
    p.add_argument("--no-probe", action="store_true", help="no speed probe between runs")
    p.add_argument("--driver", choices=DRIVERS, default="lavapipe",
                   help="Vulkan driver: 'lavapipe' (default; its ICD is set as the only one) or "
                        "'native' (the machine's own: VK_ICD_FILENAMES / VK_DRIVER_FILES left as "
                        "they are; the speed probe measures lavapipe, so add --no-probe)")
    p.add_argument("--real-devices", action="store_true",
                   help="run vmgpu without --simulate-mgpu: each GPU is a physical device of its "
                        "own (a machine with several GPUs); by default the GPUs are VkDevices "
                        "on one physical device")
    return p


def check_arguments(args: argparse.Namespace) -> None:
    """The numeric options' ranges, as one clear error each."""
    if args.frames < 2 or args.repeats < 1 or args.warmup < 0 or args.warmup >= args.frames:
        raise VmgpuMeasureError(f"expected --frames >= 2, --repeats >= 1 and 0 <= --warmup < "
                                f"--frames; got {args.frames}, {args.repeats}, {args.warmup}")
    if any(g < 1 or g > 16 for g in args.gpus):
        raise VmgpuMeasureError(f"--gpus must be 1-16, got {args.gpus}")
    if args.patch is not None and not args.patch.is_file():
        raise VmgpuMeasureError(f"--patch {args.patch}: no such file")
    if args.stall_factor <= 1 or args.run_timeout <= 0:
        raise VmgpuMeasureError("--stall-factor must be over 1 and --run-timeout over 0")


def measure(args: argparse.Namespace, argv: list[str]) -> Path:
    """The whole measurement; the output folder once written."""
    check_arguments(args)
    build = check_build(args.build)
    tables.check_out_folder(args.out)
    grid = campaign.Grid(strategies=tuple(args.strategies), gpus=tuple(args.gpus),
                         triangles=tuple(args.triangles), resolutions=tuple(args.resolutions),
                         simulate=not args.real_devices)
    grid.configs()  # a grid with nothing to run fails here, before Xvfb starts
    settings = campaign.Settings(frames=args.frames, warmup=args.warmup, repeats=args.repeats,
                                 timeout_s=args.run_timeout, stall_factor=args.stall_factor,
                                 seed=args.seed, log_dir=args.keep_logs, driver=args.driver)
    width = max(w for w, _ in grid.resolutions)
    height = max(h for _, h in grid.resolutions)
    with tempfile.TemporaryDirectory(prefix="vmgpu-meshes-") as tmp:
        mesh_dir = args.mesh_dir or Path(tmp)
        probe = NoProbe() if args.no_probe else ProjectProbe()
        try:
            ctx = provenance.context(build, args.patch, probe.module_name, argv, args.driver)
            server = Xvfb(width, height)
            with server as display:
                results = campaign.run_campaign(build, grid, settings, display, mesh_dir, probe,
                                                xvfb_pid=server.pid)
        finally:
            probe.close()
    runs = pd.DataFrame(results.runs)
    frames = pd.concat(results.frames, ignore_index=True)
    doc = provenance.text(ctx, grid, settings, runs, frames, results.end_probe, probe.errors)
    tables.write_all(args.out, runs, frames, doc)
    return args.out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parser().parse_args(argv)
    try:
        out = measure(args, ["python", "-m", "mgpusim.vmgpu", *argv])
    except VmgpuMeasureError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"wrote {out / tables.RUNS}, {out / tables.FRAMES} and {out / tables.PROVENANCE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
