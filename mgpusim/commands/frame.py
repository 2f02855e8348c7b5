"""`mgpusim frame import CAPTURE --out EXPERIMENT.toml`: a measured frame as an experiment.

The capture is a Chrome trace-event JSON file (Perfetto, browsers, engine profilers, mgpusim's
own trace.perfetto.json), a CSV table (pass, queue, gpu_ms, reads, writes, bytes) or a measured
run of the Vulkan runner (a folder with trace.parquet and summary.json). docs/formats.md,
"Frame captures", says what each must hold.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from mgpusim.io.out_folder import check_out_file
from mgpusim.model.errors import InputError

#: The profile an imported frame names unless --profile gives one: GPUs of the capture's class
#: (a captured pass costs its measured time) on PCIe 4.0 x16 links.
DEFAULT_PROFILE = "hardware_profiles/pcie4_pair.toml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("frame", help="bring your own frame: import a profiler capture as an experiment")
    steps = p.add_subparsers(dest="step", required=True, metavar="STEP")
    s = steps.add_parser("import", help="a captured frame (Chrome trace, CSV, measured run) as an experiment",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("capture", type=Path, help="a .json Chrome trace, a .csv table or a measured run's folder")
    s.add_argument("--out", type=Path, required=True, help="the experiment file to write (.toml)")
    s.add_argument("--format", choices=("auto", "chrome", "csv", "run"), default="auto",
                   help="the capture's format (default: from its name)")
    s.add_argument("--size", metavar="WxH", default=None,
                   help="the frame's resolution (required unless the capture records it: a measured run does)")
    s.add_argument("--profile", type=Path, default=None,
                   help=f"the hardware profile the experiment names (default: the shipped {DEFAULT_PROFILE})")
    s.add_argument("--pixel-share", type=float, default=1.0, metavar="F",
                   help="for passes whose capture does not say: the share of their time that scales "
                        "with the pixels they draw, the rest with their geometry (default 1)")
    s.add_argument("--cpu-thread", action="append", default=None, metavar="NAME",
                   help="a Chrome trace's thread whose slices are the frame's CPU work (default: main; repeatable)")
    s.add_argument("--name", default=None, help="the experiment's name (default: the output file's stem)")
    s.set_defaults(func=run)


def parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or not 1 <= int(m.group(1)) <= 65536 or not 1 <= int(m.group(2)) <= 65536:
        raise InputError(f"expected WxH with sides 1..65536, e.g. 1920x1080, got {text!r}", field="--size")
    return int(m.group(1)), int(m.group(2))


def run(args: argparse.Namespace) -> int:
    from mgpusim.frames.formats import detect_format, read_capture  # noqa: PLC0415
    from mgpusim.frames.importer import check_experiment, experiment_text, frame_from_slices  # noqa: PLC0415
    from mgpusim.io.shipped import shipped_dir  # noqa: PLC0415
    from mgpusim.io.writers import write_text  # noqa: PLC0415
    if not 0.0 <= args.pixel_share <= 1.0:
        raise InputError(f"must be in [0, 1], got {args.pixel_share}", field="--pixel-share")
    if args.out.suffix != ".toml":
        raise InputError(f"an experiment file ends in .toml, got {args.out}", field="--out")
    check_out_file(args.out)
    size = parse_size(args.size)
    fmt = detect_format(args.capture) if args.format == "auto" else args.format
    slices, meta = read_capture(args.capture, fmt, args.cpu_thread or ("main",))
    if size is None and "width" not in meta:
        raise InputError(f"a {fmt} capture does not record the frame's resolution: give --size WxH",
                         field="--size")
    width, height = size or (meta["width"], meta["height"])
    profile = args.profile or shipped_dir("hardware_profiles") / Path(DEFAULT_PROFILE).name
    frame = frame_from_slices(slices, name=args.name or args.out.stem, source=str(args.capture),
                              width=width, height=height, pixel_share=args.pixel_share,
                              left_out=meta.get("left_out"), origin=meta.get("source"))
    text = experiment_text(frame, profile, args.out)
    exp = check_experiment(text, args.out)
    write_text(text, args.out)
    print(f"{args.capture}: {len(frame.passes)} pass(es) over {frame.frames} frame(s), "
          f"{frame.gpu_ms:.3f} ms of GPU time per frame"
          + (f" per eye ({frame.views} views)" if frame.views == 2 else "")
          + (f", {frame.cpu_ms:.3f} ms CPU" if frame.cpu_ms else "") + f", {width}x{height}")
    for note in frame.notes:
        print(f"  note: {note}")
    print(f"  wrote {args.out} (profile {exp.profile.name}); next: mgpusim advise {args.out}")
    return 0
