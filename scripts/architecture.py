"""Draw docs/architecture.md's package picture and table from the real import graph.

    python scripts/architecture.py            # rewrite docs/img/architecture.png and the table
    python scripts/architecture.py --check    # exit 1 if the committed table differs from the code

The layers come from pyproject.toml's import-linter contract (the one the tests check); the
arrows are the imports grimp finds between packages; the table lists every package with its
modules and the first paragraph of its docstring (no line counts: the table changes when the
packages do, not with every edit).
"""
from __future__ import annotations

import argparse
import ast
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
PICTURE = ROOT / "docs" / "img" / "architecture.png"
BEGIN, END = "<!-- packages: begin (scripts/architecture.py) -->", "<!-- packages: end -->"


def layers() -> list[list[str]]:
    """Top to bottom, each layer's packages (short names), from the first layers contract."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    contract = config["contracts"][0]
    return [[p.strip().removeprefix("mgpusim.") for p in layer.split("|")] for layer in contract["layers"]]


def package_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "mgpusim"


def package_edges() -> set[tuple[str, str]]:
    import grimp  # noqa: PLC0415 - a test dependency, only this script needs it
    graph = grimp.build_graph("mgpusim")
    edges = set()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            a, b = package_of(module), package_of(imported)
            if a != b and a != "mgpusim" and a != "__main__":
                edges.add((a, b))
    return edges


def table() -> str:
    rows = ["| package | modules | what it holds |", "|---|---|---|"]
    for layer in layers():
        for name in layer:
            folder = ROOT / "mgpusim" / name
            files = sorted(folder.rglob("*.py")) if folder.is_dir() else [folder.with_suffix(".py")]
            init = folder / "__init__.py" if folder.is_dir() else folder.with_suffix(".py")
            doc = (ast.get_docstring(ast.parse(init.read_text())) or "").split("\n\n")[0]
            doc = " ".join(doc.split())
            mods = [f.relative_to(folder).with_suffix("").as_posix() for f in files
                    if f.name != "__init__.py"] if folder.is_dir() else [name]
            rows.append(f"| `{name}` | {len(mods)}: {', '.join(f'`{m}`' for m in mods)} | {doc} |")
    return "\n".join(rows)


def draw(path: Path) -> None:
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    rows = layers()
    pos = {}
    for i, layer in enumerate(rows):
        for j, name in enumerate(layer):
            pos[name] = ((j + 1) / (len(layer) + 1), 1 - i / (len(rows) - 1))
    fig, ax = plt.subplots(figsize=(8, 9))
    for a, b in sorted(package_edges()):
        if a in pos and b in pos:
            (x0, y0), (x1, y1) = pos[a], pos[b]
            ax.annotate("", xy=(x1, y1 + 0.02), xytext=(x0, y0 - 0.02),
                        arrowprops=dict(arrowstyle="->", color="0.6", lw=0.8,
                                        connectionstyle="arc3,rad=0.15"))
    for name, (x, y) in pos.items():
        ax.text(x, y, name, ha="center", va="center", fontsize=11,
                bbox=dict(boxstyle="round", fc="#e8f0fe", ec="#3367d6"))
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.06, 1.06)
    ax.axis("off")
    ax.set_title("mgpusim's packages: each imports only those below it (arrows: imports)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def with_table(text: str) -> str:
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="only check that the table is current")
    args = p.parse_args()
    text = DOC.read_text()
    if args.check:
        current = with_table(text) == text
        print("docs/architecture.md: table " + ("current" if current else "differs from the code"))
        return 0 if current else 1
    DOC.write_text(with_table(text))
    draw(PICTURE)
    print(f"wrote {DOC.relative_to(ROOT)} and {PICTURE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
