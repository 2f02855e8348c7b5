"""The package's layers: imports point down, no module imports itself through others, and no two
modules share a name (so a name in a traceback or a doc says which module it is)."""
from __future__ import annotations

import subprocess
import sys
from collections import Counter
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]


def _import_cycles(graph: grimp.ImportGraph) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.find_modules_directly_imported_by(child)))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(component)
    return cycles


def test_the_layer_contracts_hold():
    """pyproject.toml's import-linter contracts: cli > commands > studies > calibration >
    validation > io | real | sim > results > schedules > model."""
    lint = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    run = subprocess.run([sys.executable, "-c", lint, "--no-cache"], cwd=ROOT, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "2 kept, 0 broken" in run.stdout  # both contracts were read and checked


def test_no_import_cycle():
    assert _import_cycles(grimp.build_graph("mgpusim")) == []


def test_the_cycle_finder_finds_a_cycle():
    graph = grimp.ImportGraph()
    for name in ("p", "p.a", "p.b", "p.c"):
        graph.add_module(name)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.a")
    graph.add_import(importer="p.c", imported="p.a")
    assert _import_cycles(graph) == [{"p.a", "p.b"}]


def test_no_two_modules_share_a_name():
    """A name finds one module, except that a command's module is named for the package it is
    the command of (`commands/advise.py` fronts `advise/`)."""
    files = [p for p in (ROOT / "mgpusim").rglob("*.py") if p.stem != "__main__"]
    names = Counter(p.stem if p.stem != "__init__" else p.parent.name for p in files)
    names["mgpusim"] -= 1  # the root package itself
    packages = {p.parent.name for p in files if p.stem == "__init__"}
    commands = {p.stem for p in files if p.parent.name == "commands"}
    fronted = packages & commands
    assert {n for n, count in names.items() if count > 1} == {n for n in fronted if names[n] == 2}
    assert fronted <= {"advise", "bench", "measure"}


def test_the_architecture_page_lists_the_packages_as_they_are():
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "architecture.py"), "--check"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
