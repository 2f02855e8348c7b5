"""`mgpusim fidelity [--data DIR] [--out DIR] [--docs]`: every committed measured configuration at every
fidelity level: error against the measurement and simulation time (the accuracy/time table)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mgpusim.io.out_folder import check_out_dir
from mgpusim.model.errors import InputError

if TYPE_CHECKING:  # annotations only: loaded when the command runs
    import pandas as pd

DOCS = Path(__file__).resolve().parents[2] / "docs"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fidelity", help="error vs measured runs and simulation time, per fidelity level")
    p.add_argument("--data", type=Path, default=Path("data"),
                   help="a checkout's data/ folder: the committed measured runs (default: ./data)")
    p.add_argument("--out", type=Path, default=Path("out") / "fidelity",
                   help="folder for per_config.csv, levels.csv, fidelity.md and fidelity_pareto.png")
    p.add_argument("--repeats", type=int, default=3, help="best of this many timed runs per configuration")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar on stderr")
    p.add_argument("--docs", action="store_true",
                   help="also write the table into docs/fidelity.md and the plot to docs/img/fidelity_pareto.png")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.bench.accuracy_cost import (  # noqa: PLC0415
        committed_sources,
        configurations,
        deviations,
        deviations_markdown,
        markdown,
        run_levels,
        summarize_deviations,
        summarize_levels,
    )
    from mgpusim.io.writers import write_table  # noqa: PLC0415
    if args.docs and not (DOCS / "fidelity.md").is_file():
        raise InputError(f"needs a checkout with {DOCS / 'fidelity.md'}", field="--docs")
    sources = committed_sources(args.data)
    check_out_dir(args.out)  # before any work
    from mgpusim.bench.accuracy_cost import VARIANTS  # noqa: PLC0415
    from mgpusim.io.progress import bar  # noqa: PLC0415
    from mgpusim.io.shipped import examples  # noqa: PLC0415
    configs = configurations(sources)
    with bar((len(configs) + len(examples())) * len(VARIANTS), "fidelity", "run", args.progress) as shown:
        def step(name: str) -> None:
            shown.set_postfix_str(name, refresh=False)
            shown.update(1)
        table = run_levels(configs, repeats=max(1, args.repeats), progress=step)
        runs = deviations(repeats=max(1, args.repeats), progress=step)
    levels = summarize_levels(table)
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(table, args.out / "per_config.csv")
    write_table(levels, args.out / "levels.csv")
    dev = summarize_deviations(runs)
    write_table(dev, args.out / "deviations.csv")
    text = markdown(levels)
    dev_text = deviations_markdown(dev)
    (args.out / "fidelity.md").write_text(text + "\n" + dev_text)
    pareto_png(levels, args.out / "fidelity_pareto.png", dev)
    counts = table.drop_duplicates(["machine", "config"])["machine"].value_counts()
    print(f"{len(configs)} measured configurations (" + ", ".join(f"{n} on {m}" for m, n in counts.items()) + ")")
    print(text, end="")
    print("\nshipped experiments, each level against full (no measurement):")
    print(dev_text, end="")
    if args.docs:
        _write_docs({"fidelity table": text, "deviation table": dev_text}, levels, dev)
    print(f"  wrote {args.out}")
    return 0


def pareto_png(levels: pd.DataFrame, path: Path, deviations: pd.DataFrame | None = None) -> Path:
    """Left: median |frame-time error| against measured runs vs the model's median time per
    configuration (one colour per level, one marker per schedule, large: all schedules).
    Right: each level's median |frame time - full| on the shipped experiments vs its time.
    Both log-log."""
    import matplotlib  # noqa: PLC0415 (plotting stays at the edge)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.ticker import NullFormatter, ScalarFormatter  # noqa: PLC0415
    panels = 2 if deviations is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(6.0 * panels, 4.4), dpi=120, squeeze=False)
    markers = {"all": "o", "sort_first": "^", "sort_last": "v"}
    colour = {level: f"C{i}" for i, level in enumerate(dict.fromkeys(levels["level"]))}
    ax = axes[0][0]
    r: Any  # a row's fields (pandas-stubs types each as any scalar)
    for r in levels.itertuples(index=False):
        ax.scatter(r.median_model_ms, max(r.median_abs_frame_time_error, 1e-4) * 100, color=colour[r.level],
                   marker=markers.get(r.schedule, "s"), s=80 if r.schedule == "all" else 30,
                   label=r.level if r.schedule == "all" else None, alpha=0.9)
    ax.set_title("vs measured NVIDIA runs\n(o all, ^ sort-first, v sort-last)", fontsize=10)
    ax.set_ylabel("median |frame-time error|, % (log)")
    if deviations is not None:
        ax2 = axes[0][1]
        for r in deviations.itertuples(index=False):
            ax2.scatter(r.median_model_ms, max(r.worst_abs_deviation, 1e-4) * 100, color=colour.get(r.level, "k"),
                        marker="D", s=60, label=r.level)
        ax2.set_title("vs full, shipped experiments (no measurement)", fontsize=10)
        ax2.set_ylabel("worst |frame time - full|, % (log; 0 drawn at 0.01)")
    for a in axes[0]:
        a.set_xscale("log")
        a.set_yscale("log")
        for axis in (a.xaxis, a.yaxis):
            axis.set_major_formatter(ScalarFormatter())
        a.xaxis.set_minor_formatter(ScalarFormatter())
        if a.get_ylim()[1] / a.get_ylim()[0] < 10:  # less than a decade: label the minor ticks too
            a.yaxis.set_minor_formatter(ScalarFormatter())
        else:
            a.yaxis.set_minor_formatter(NullFormatter())
        a.tick_params(which="minor", labelsize=7)
        a.set_xlabel("model time per configuration, ms (median; log)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8, loc="center")
    fig.suptitle("What accuracy costs in time, per fidelity level", fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _write_docs(tables: dict[str, str], levels: pd.DataFrame, deviations: pd.DataFrame) -> None:
    """Replace each `<!-- NAME -->`...`<!-- end NAME -->` block of docs/fidelity.md; the plot."""
    doc = DOCS / "fidelity.md"
    text = doc.read_text()
    for name, table in tables.items():
        start, end = f"<!-- {name} -->", f"<!-- end {name} -->"
        if start in text and end in text:
            head, _, rest = text.partition(start)
            _, _, tail = rest.partition(end)
            text = f"{head}{start}\n{table}{end}{tail}"
    doc.write_text(text)
    (DOCS / "img").mkdir(exist_ok=True)
    pareto_png(levels, DOCS / "img" / "fidelity_pareto.png", deviations)
