"""The cyclic garbage collector run less often while a command does many small computations.

Why: a sweep's points and an advise's options each allocate thousands of small objects (a
program, a model, a summary), and the collector's default thresholds went over them, and over
everything already alive, so often that it took a quarter to a third of the CPU (docs/bench.md).
Nothing computed depends on when garbage is collected; cyclic garbage still is, later.
"""
from __future__ import annotations

import contextlib
import gc
from typing import Iterator


@contextlib.contextmanager
def fewer_collections(young: int, older: tuple[int, int] | None = None) -> Iterator[None]:
    """Until the block ends: `young` allocations between young-generation runs (`older`: the
    two older generations' thresholds, None keeps them), and what exists now (modules, the
    parsed inputs) frozen out of the collector's runs, in this process and in workers forked
    from it. Afterwards the collector is as it was; a freeze the caller made stays theirs."""
    before = gc.get_threshold()
    ours = not gc.get_freeze_count()
    if ours:
        gc.freeze()
    gc.set_threshold(young, *(older or before[1:]))
    try:
        yield
    finally:
        gc.set_threshold(*before)
        if ours:
            gc.unfreeze()
