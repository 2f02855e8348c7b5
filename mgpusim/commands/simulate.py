"""`mgpusim simulate EXPERIMENT [--set key=value ...] [--out DIR] [--frames A:B] [--trace-frames N]`."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mgpusim.io.defaults import PERFETTO_SLICES, TRACE_FRAMES, TRACE_ROWS
from mgpusim.io.out_folder import check_out_dir
from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    from mgpusim.sim.effect_names import EFFECT_NAMES, FIDELITIES  # noqa: PLC0415 - names only: no model
    p = sub.add_parser("simulate", help="run an experiment in the model and write its results")
    p.add_argument("experiment", help="experiment TOML file, or a shipped name (`mgpusim examples`)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="override a field, e.g. schedule.gpus=3 or scene.width=1920 (repeatable)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: out/<experiment name>)")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="trace table format")
    p.add_argument("--fidelity", choices=FIDELITIES, default="full",
                   help="analytic (no event simulation), queues (fixed-rate links, no shared executor) "
                        "or full (default); see docs/fidelity.md")
    p.add_argument("--effects", default=None, metavar="+X,-Y",
                   help=f"force effects on (+) or off (-): {', '.join(EFFECT_NAMES)}")
    p.add_argument("--no-fast-forward", dest="fast_forward", action="store_false",
                   help="simulate every frame even once the model's state repeats (same results, slower)")
    p.add_argument("--frames", metavar="A:B", default=None,
                   help="frames A to B-1 drawn in timeline.png (default: the last four; a window past "
                        "the run's end is clipped to it, with a note)")
    p.add_argument("--trace-frames", type=int, default=None, metavar="N",
                   help=f"the last N frames go into trace.perfetto.json (default: {TRACE_FRAMES}, "
                        f"fewer where they hold over {PERFETTO_SLICES:,} tasks; 0: all)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no progress bar on stderr (it appears only for runs that take over a second)")
    p.add_argument("--trace-rows", type=int, default=TRACE_ROWS, metavar="N",
                   help=f"the trace table holds the whole run up to N rows, else its first frames "
                        f"that fit (default: {TRACE_ROWS:,}; 0: always the whole run)")
    p.set_defaults(func=run)


def parse_frames(text: str) -> range:
    """``A:B`` -> frames A..B-1 (as a Python slice; both ends needed), in ASCII digits (str.isdigit
    takes '²', which int() refuses), each at most MAX_FRAMES (no run has more frames)."""
    from mgpusim.model.limits import MAX_FRAMES  # noqa: PLC0415
    lo, sep, hi = (part.strip() for part in text.partition(":"))
    if not sep or not (lo + hi).isascii() or not lo.isdigit() or not hi.isdigit() or len(lo + hi) > 40:
        raise InputError(f"expected A:B with whole numbers A < B in ASCII digits (frames A to B-1), "
                         f"got {text[:40]!r}", field="--frames")
    if int(hi) > MAX_FRAMES:
        raise InputError(f"B must be <= {MAX_FRAMES:g} (no run has more frames), got {hi}", field="--frames")
    if int(hi) <= int(lo):
        raise InputError(f"expected A < B (frames A to B-1), got {text!r}", field="--frames")
    return range(int(lo), int(hi))


def clip_frames(frames: range | None, total: int) -> tuple[range | None, list[str]]:
    """`--frames A:B` within a run of `total` frames: past its end is refused, a window that
    runs over it is clipped to it with a note (the timeline draws what exists and says so)."""
    if frames is None or frames.stop <= total:
        return frames, []
    if frames.start >= total:
        raise InputError(f"frames {frames.start}:{frames.stop} lie past the run's {total} frames "
                         f"(give A < {total})", field="--frames")
    return range(frames.start, total), [f"--frames {frames.start}:{frames.stop} runs past the run's "
                                        f"{total} frames: timeline.png draws frames {frames.start}-{total - 1}"]


def run(args: argparse.Namespace) -> int:
    from mgpusim.io.writers import write_result  # noqa: PLC0415
    from mgpusim.schedules.experiment import load_experiment, parse_overrides  # noqa: PLC0415
    from mgpusim.sim.effects import parse_effects  # noqa: PLC0415
    from mgpusim.sim.simulation import simulate  # noqa: PLC0415
    frames = parse_frames(args.frames) if args.frames else None
    for name in ("trace_frames", "trace_rows"):
        value = getattr(args, name)
        if value is not None and value < 0:
            raise InputError(f"must be >= 0, got {value}", field="--" + name.replace("_", "-"))
    exp = load_experiment(resolve_experiment(args.experiment), parse_overrides(args.overrides))
    frames, clipped = clip_frames(frames, exp.schedule.frames)
    out = args.out or Path("out") / exp.name
    check_out_dir(out)
    from mgpusim.io.progress import bar, reporter  # noqa: PLC0415
    forced = parse_effects(args.effects)
    with bar(exp.schedule.frames, "simulate", "frame", args.progress) as shown:
        result = simulate(exp, fidelity=args.fidelity, effects=forced,
                          fast_forward=args.fast_forward, band=True, progress=reporter(shown))
    with bar(6, "write", "file", args.progress) as shown:
        def writing(name: str) -> None:
            shown.set_postfix_str(name, refresh=False)
            shown.update(1)
        files = write_result(result, out, args.format, title=f"{exp.name}: {exp.schedule.name}, "
                             f"{exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}",
                             frames=frames, trace_frames=args.trace_frames, trace_rows=args.trace_rows,
                             progress=writing)
    s = result.summary
    for warning in s.get("warnings", []):
        print(f"mgpusim simulate: warning: {warning} (summary.json `warnings`)", file=sys.stderr)
    print(f"{exp.name}: {exp.schedule.name} on {exp.schedule.gpus} GPU(s) of {exp.profile.name}, "
          f"{exp.scene.width}x{exp.scene.height}")
    print(f"  frame time {s['frame_time_ms']:.3f} ms ({s['fps']:.1f} fps), latency {s['latency_ms']:.3f} ms, "
          f"jitter {s['frame_time_jitter_ms']:.3f} ms")
    if "frame_time_ms_lo" in s:
        print(f"  calibration band (pass costs +-1 standard error): frame time {s['frame_time_ms_lo']:.3f}"
              f"-{s['frame_time_ms_hi']:.3f} ms, latency {s['latency_ms_lo']:.3f}-{s['latency_ms_hi']:.3f} ms")
    for name, hz in s.get("task_rates_hz", {}).items():
        if name != "frames":
            print(f"  {name}: {hz:.1f} Hz (frames {s['fps']:.1f} Hz)")
    ff = s.get("fast_forward", {})
    print(f"  fidelity {s['fidelity']}; effects {', '.join(s['modelled_effects']) or 'none'}"
          + (f"; fast-forward: {ff['why']}" if ff.get("used") else ""))
    if "approximations" in s:
        print("  approximations (summary.json `approximations`): "
              + ("; ".join(s["approximations"]) or "none: this scene needs no effect the level omits"))
    busiest = sorted(s.get("utilization", {}).items(), key=lambda kv: -kv[1])[:4]
    print("  busiest: " + ", ".join(f"{k} {v:.0%}" for k, v in busiest))
    print(f"  wrote {', '.join(str(p) for p in files.values())}")
    for note in clipped + settle_notes(s) + window_notes(result, args) + effects_notes(exp, result.summary, forced):
        print(f"  note: {note}")
    return 0


def settle_notes(summary: dict) -> list[str]:
    """One line when the run's frame time or latency had not settled by its end (summary.json
    `settled`, :mod:`mgpusim.results.settled`): its figures are not the steady state's."""
    return [] if summary.get("settled", True) else [summary["settling"]["note"]]


def effects_notes(exp, summary: dict, forced: dict[str, bool] | None) -> list[str]:
    """One line when the fidelity level left out effects that this scene needs (those `full`
    would model), so that a figure is not read as the full model's."""
    from mgpusim.sim.effects import choose_effects  # noqa: PLC0415
    from mgpusim.sim.simulation import build_program  # noqa: PLC0415
    if summary["fidelity"] == "full":
        return []
    needed = choose_effects(build_program(exp), exp.profile)
    left = sorted(needed - set(summary["modelled_effects"]) - {n for n, on in (forced or {}).items() if not on})
    if not left:
        return []
    return [f"--fidelity {summary['fidelity']} left out {', '.join(left)}, which this scene needs: "
            "figures may differ from full's (docs/fidelity.md)"]


def window_notes(result, args: argparse.Namespace) -> list[str]:
    """What the files leave out of a run too large to hold whole, and how to get it."""
    from mgpusim.io.writers import perfetto_frames, table_frames  # noqa: PLC0415
    n, notes = len(result.frames), []
    kept = table_frames(result, args.trace_rows)
    if kept < n:
        notes.append(f"the trace table holds frames 0-{kept - 1} of {n} (over {args.trace_rows:,} "
                     "rows; --trace-rows 0 writes all)")
    shown = perfetto_frames(result, args.trace_frames)
    if args.trace_frames is None and shown < min(TRACE_FRAMES, n):
        notes.append(f"trace.perfetto.json holds the last {shown} frames (at most {PERFETTO_SLICES:,} "
                     "tasks; --trace-frames N to choose)")
    return notes
