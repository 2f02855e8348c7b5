"""`mgpusim case NAME [--out DIR] [--frames N]` and `mgpusim case --list`: a case study in one command.

Simulates every run of a shipped case (`experiments/cases/<name>/case.toml`) and writes the
predicted table (`predictions.md`, `predictions.csv`), the source's published figures beside
their predictions (`comparison.csv`: quantity, published, predicted, error) and a timeline
picture per run the case names (`timeline_<run>.png`) into the output folder. `--calibrate`
instead finds the values the published figures set (the case's calibration rules) and prints
them beside the case file's.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from mgpusim.io.out_folder import check_out_dir
from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_FRAMES, WHY_FRAMES

if TYPE_CHECKING:  # annotations only: loaded when the command runs
    from mgpusim.cases.case_file import CaseResult


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("case", help="run a case study (a source system's own setup) and write its predictions",
                       description=__doc__.splitlines()[0])
    p.add_argument("name", nargs="?", help="a shipped case (`mgpusim case --list`) or a case.toml path")
    p.add_argument("--list", action="store_true", help="list the shipped cases and exit")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: out/cases/<name>)")
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="simulate N frames per run (a fifth of them warm-up) instead of each experiment's own")
    p.add_argument("--calibrate", action="store_true",
                   help="find the parameter values the published figures set and print them (writes nothing)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.cases.case_file import (  # noqa: PLC0415
        case_names,
        comparison,
        comparison_markdown,
        extrapolation_markdown,
        load_case,
        markdown,
        run_case,
        table,
    )
    from mgpusim.io.writers import write_table, write_text  # noqa: PLC0415
    if args.list:
        for name in case_names():
            case = load_case(name)
            print(f"{name:18s} {len(case.runs):3d} runs  {case.title}")
        return 0
    if not args.name:
        raise InputError("give a case name (`mgpusim case --list` lists them)", field="NAME")
    if args.frames is not None and not 2 <= args.frames <= MAX_FRAMES:
        raise InputError(f"must be in 2..{MAX_FRAMES:g} ({WHY_FRAMES}), got {args.frames}", field="--frames")
    case = load_case(args.name)
    if args.calibrate:
        return print_calibration(case, args.frames)
    out = args.out or Path("out") / "cases" / case.name
    check_out_dir(out)
    from mgpusim.io.progress import bar  # noqa: PLC0415
    steps = sum(1 for r in case.runs if r.simulate) + len(case.timelines)
    with bar(steps, "case", "step", args.progress) as shown:
        def step(name: str) -> None:
            shown.set_postfix_str(name, refresh=False)
            shown.update(1)
        result = run_case(case, args.frames, progress=step)
        out.mkdir(parents=True, exist_ok=True)
        text = f"# {case.title}\n\n{case.description}\n\n{markdown(result)}"
        if case.published:
            text += f"\n## Compared with the published figures\n\n{comparison_markdown(result)}"
        beyond = extrapolation_markdown(result)
        if beyond:
            text += ("\n## Beyond the fitted point: 3 GPUs and more beside Amdahl's line\n\n"
                     "Each gain at 3 or more GPUs as predicted, beside the Amdahl line through "
                     f"the same schedule's 1 -> 2 GPU gain.\n\n{beyond}")
        files = [write_text(text, out / "predictions.md"), write_table(table(result), out / "predictions.csv")]
        if case.published:
            files.append(write_table(comparison(result), out / "comparison.csv"))
        files += write_timelines(result, out, "timeline_", lambda name: step(f"timeline {name}"))
    print(text, end="")
    print(f"\nwrote {', '.join(str(f) for f in files)}")
    return 0


def print_calibration(case, frames: int | None) -> int:
    """The values the case's published figures set, beside the case file's."""
    from mgpusim.cases.case_file import calibrate  # noqa: PLC0415
    found = calibrate(case, frames)
    print(f"{case.name}: parameters set by published figures (calibration rules of {case.file})")
    for fig in case.published:
        if fig.sets:
            par = case.parameter(fig.sets)
            how = "searched" if par.bounds else "a rule's value (not searched)"
            print(f"  {par.name}: {found[par.name]:.6g} (case file: {par.value:.6g}; {how}) "
                  f"<- {fig.label} = {fig.value:g}")
    return 0


def write_timelines(result: CaseResult, folder: Path, prefix: str,
                    progress: Callable[[str], None] | None = None) -> list[Path]:
    """A timeline picture of the last frames of every run the case names: `<prefix><run>.png`.
    `progress(run)`: called before each picture."""
    from mgpusim.io.plot import last_frames, timeline_png  # noqa: PLC0415
    case, files = result.case, []
    for name in case.timelines:
        if progress is not None:
            progress(name)
        res, run_ = result.results[name], case.run(name)
        frames = last_frames(res.trace, case.timeline_frames)
        files.append(timeline_png(res.trace, folder / f"{prefix}{name}.png", res.links,
                                  f"{case.name} / {name}: {run_.label}", frames))
    return files
