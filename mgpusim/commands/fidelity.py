"""`mgpusim fidelity [--out DIR] [--docs]`: every committed measured configuration at every
fidelity level: error against the measurement and simulation time (the accuracy/time table)."""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from ..fidelity import configurations, markdown, run_levels, summarize_levels
from ..output import write_table

DOCS = Path(__file__).resolve().parents[2] / "docs"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fidelity", help="error vs measured runs and simulation time, per fidelity level")
    p.add_argument("--out", type=Path, default=Path("out") / "fidelity",
                   help="folder for per_config.csv, levels.csv, fidelity.md and fidelity_pareto.png")
    p.add_argument("--repeats", type=int, default=3, help="best of this many timed runs per configuration")
    p.add_argument("--docs", action="store_true",
                   help="also write the table into docs/fidelity.md and the plot to docs/img/fidelity_pareto.png")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    configs = configurations()
    table = run_levels(configs, repeats=max(1, args.repeats))
    levels = summarize_levels(table)
    write_table(table, args.out / "per_config.csv")
    write_table(levels, args.out / "levels.csv")
    text = markdown(levels)
    (args.out / "fidelity.md").write_text(text)
    pareto_png(levels, args.out / "fidelity_pareto.png")
    counts = table.drop_duplicates(["machine", "config"])["machine"].value_counts()
    print(f"{len(configs)} measured configurations (" + ", ".join(f"{n} on {m}" for m, n in counts.items()) + ")")
    print(text, end="")
    if args.docs:
        _write_docs(text, levels, len(configs))
    print(f"  wrote {args.out}")
    return 0


def pareto_png(levels: pd.DataFrame, path: Path) -> Path:
    """Median |frame-time error| against the model's median time per configuration, log-log:
    one colour per level, one marker per schedule (large: all schedules)."""
    import matplotlib  # noqa: PLC0415 (plotting stays at the edge)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.ticker import ScalarFormatter  # noqa: PLC0415
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    markers = {"all": "o", "sort_first": "^", "sort_last": "v"}
    for i, (level, g) in enumerate(levels.groupby("level", sort=False)):
        for r in g.itertuples(index=False):
            ax.scatter(r.median_model_ms, max(r.median_abs_frame_time_error, 1e-4) * 100, color=f"C{i}",
                       marker=markers.get(r.schedule, "s"), s=80 if r.schedule == "all" else 30,
                       label=level if r.schedule == "all" else None, alpha=0.9)
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(ScalarFormatter())
        axis.set_minor_formatter(ScalarFormatter())
    ax.tick_params(which="minor", labelsize=7)
    ax.set_xlabel("model time per configuration, ms (median; log)")
    ax.set_ylabel("median |frame-time error|, % (log)")
    ax.set_title("Accuracy vs time per fidelity level\n(measured NVIDIA runs; o all, ^ sort-first, v sort-last)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="center")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _write_docs(table: str, levels: pd.DataFrame, n: int) -> None:
    doc = DOCS / "fidelity.md"
    text = doc.read_text()
    start, end = "<!-- fidelity table -->", "<!-- end fidelity table -->"
    if start in text and end in text:
        head, _, rest = text.partition(start)
        _, _, tail = rest.partition(end)
        doc.write_text(f"{head}{start}\n{table}{end}{tail}")
    (DOCS / "img").mkdir(exist_ok=True)
    pareto_png(levels, DOCS / "img" / "fidelity_pareto.png")
