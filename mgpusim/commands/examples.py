"""`mgpusim examples`: the shipped experiments, by the names every command accepts."""
from __future__ import annotations

import argparse

from mgpusim.io.shipped import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("examples", help="list the shipped experiments (their names work as EXPERIMENT)",
                       description=__doc__)
    p.add_argument("--paths", action="store_true", help="print each experiment's file path too")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    items = examples()
    width = max(len(e.name) for e in items)
    for e in items:
        print(f"{e.name:{width}s}  {e.schedule:12s} {e.gpus} GPU(s)  {e.description}")
        if args.paths:
            print(f"{'':{width}s}  {e.path}")
    print(f"\ne.g. mgpusim simulate {items[0].name} --set schedule.gpus=3")
    return 0
