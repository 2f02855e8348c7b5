"""`mgpusim frame import CAPTURE [--out DIR]`: a measured frame as an experiment.

The capture is a Chrome trace-event JSON file (Perfetto, browsers, engine profilers, mgpusim's
own trace.perfetto.json), a CSV table (pass, queue, gpu_ms, reads, writes, bytes), a RenderDoc
capture (.rdc: its frame replayed with RenderDoc's Python module, which times each action on the
replaying GPU) or a measured run of the Vulkan runner (a folder with trace.parquet and
summary.json; a study's folder of repeated runs reads its steady/ window, else run0/; AFR and
pipelining runs on several GPUs give each pass where it ran). docs/frame_captures.md
says what each must hold. The experiment is written into the output folder as <name>.toml (the
capture's stem unless --name), or to the file --out names where it ends in .toml. Each pass's
pixel share comes from the capture, else --pixel-share, else is inferred from the pass's name,
targets and reads; the file says which, pass by pass.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from mgpusim.io.out_folder import check_out_dir, check_out_file
from mgpusim.model.errors import InputError

#: The profile an imported frame names unless --profile gives one: GPUs of the capture's class
#: (a captured pass costs its measured time) on PCIe 4.0 x16 links.
DEFAULT_PROFILE = "hardware_profiles/pcie4_pair.toml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("frame", help="bring your own frame: import a profiler capture as an experiment")
    steps = p.add_subparsers(dest="step", required=True, metavar="STEP")
    s = steps.add_parser("import", help="a captured frame (Chrome trace, CSV, RenderDoc, measured run) as "
                                            "an experiment",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("capture", type=Path,
                   help="a .json Chrome trace, a .csv table, a .rdc RenderDoc capture or a measured run's folder")
    s.add_argument("--out", type=Path, default=None,
                   help="output folder: the experiment is DIR/<name>.toml (default: out/<capture's stem>); "
                        "a path ending in .toml is the experiment file itself")
    s.add_argument("--format", choices=("auto", "chrome", "csv", "run", "renderdoc"), default="auto",
                   help="the capture's format (default: from its name)")
    s.add_argument("--size", metavar="WxH", default=None,
                   help="the frame's resolution (required unless the capture records it: a measured run, a "
                        "CSV's width and height columns, a Chrome trace's metadata, a RenderDoc capture's "
                        "targets; given, it wins)")
    s.add_argument("--profile", type=Path, default=None,
                   help=f"the hardware profile the experiment names (default: the shipped {DEFAULT_PROFILE})")
    s.add_argument("--pixel-share", type=float, default=None, metavar="F",
                   help="for passes whose capture does not say: the share of their time that scales "
                        "with the pixels they draw, the rest with their geometry (default: inferred "
                        "per pass from its name, targets and reads)")
    s.add_argument("--cpu-thread", action="append", default=None, metavar="NAME",
                   help="a Chrome trace's thread whose slices are the frame's CPU work (default: main; repeatable)")
    s.add_argument("--name", default=None,
                   help="the experiment's name (default: the output file's stem, else the capture's)")
    s.set_defaults(func=run)


def parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or not 1 <= int(m.group(1)) <= 65536 or not 1 <= int(m.group(2)) <= 65536:
        raise InputError(f"expected WxH with sides 1..65536, e.g. 1920x1080, got {text!r}", field="--size")
    return int(m.group(1)), int(m.group(2))


def out_file(out: Path | None, capture: Path, name: str | None) -> Path:
    """The experiment file: --out itself where it ends in .toml, else <name>.toml in the
    folder --out names (default out/<capture's stem>), <name> the capture's stem unless given."""
    if out is not None and out.suffix.lower() == ".toml":
        return out
    stem = name or capture.stem or "frame"
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", stem) or len(stem) > 120:
        raise InputError(f"cannot name a file after {stem!r}: give --name (letters, digits, . _ -)",
                         field="--name")
    return (out if out is not None else Path("out") / stem) / f"{stem}.toml"


def run(args: argparse.Namespace) -> int:
    from mgpusim.frames.formats import detect_format, read_capture  # noqa: PLC0415
    from mgpusim.frames.importer import check_experiment, experiment_text, frame_from_slices  # noqa: PLC0415
    from mgpusim.frames.shares import INFERRED  # noqa: PLC0415
    from mgpusim.io.shipped import shipped_dir  # noqa: PLC0415
    from mgpusim.io.writers import write_text  # noqa: PLC0415
    if args.pixel_share is not None and not 0.0 <= args.pixel_share <= 1.0:
        raise InputError(f"must be in [0, 1], got {args.pixel_share}", field="--pixel-share")
    out = out_file(args.out, args.capture, args.name)
    if out == args.out:
        check_out_file(out)
    else:
        check_out_dir(out.parent)
    size = parse_size(args.size)
    fmt = detect_format(args.capture) if args.format == "auto" else args.format
    slices, meta = read_capture(args.capture, fmt, args.cpu_thread or ("main",))
    if size is None and "width" not in meta:
        raise InputError(f"this {fmt} capture does not record the frame's resolution: give --size WxH",
                         field="--size")
    width, height = size or (meta["width"], meta["height"])
    notes = []
    if size is not None and "width" in meta and (meta["width"], meta["height"]) != size:
        notes.append(f"the capture says {meta['width']}x{meta['height']}; --size {width}x{height} wins")
    profile = args.profile or shipped_dir("hardware_profiles") / Path(DEFAULT_PROFILE).name
    frame = frame_from_slices(slices, name=args.name or out.stem, source=str(args.capture),
                              width=width, height=height, pixel_share=args.pixel_share,
                              left_out=meta.get("left_out"), origin=meta.get("source"),
                              share_why=meta.get("share_why"), read_notes=meta.get("notes", ()),
                              frames_are=meta.get("frames_are", "captured frame(s)"))
    text = experiment_text(frame, profile, out)
    exp = check_experiment(text, out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(text, out)
    print(f"{args.capture}: {len(frame.passes)} pass(es) over {frame.frames} {frame.frames_are}, "
          f"{frame.gpu_ms:.3f} ms of GPU time per frame"
          + (f" per eye ({frame.views} views)" if frame.views == 2 else "")
          + (f", {frame.cpu_ms:.3f} ms CPU" if frame.cpu_ms else "") + f", {width}x{height}"
          + ("" if size else " (the capture's size)"))
    for note in notes + list(frame.notes):
        print(f"  note: {note}")
    inferred = [p for p in frame.passes if p.share is not None and p.share.source == INFERRED]
    if inferred:
        print(f"  pixel_share inferred for {len(inferred)} of {len(frame.passes)} pass(es) (each one's reason "
              "is in the file; check them):")
        for p in inferred:
            print(f"    {p.name}: {p.pixel_share:g}  ({p.share.why if p.share else ''})")
    print(f"  wrote {out} (profile {exp.profile.name}); next: mgpusim advise {out}")
    return 0
