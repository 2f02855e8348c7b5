"""How many worker processes a command spreads independent work over.

A study's calibration grid and its comparisons, each independent of the others, run in forked
workers, one per core this process may use. `MGPUSIM_WORKERS` caps that number (1: everything
in this process): for a machine shared with other work, and for a test suite that already runs
one process per core (the project's runs its tests so).
"""
from __future__ import annotations

import multiprocessing
import os

from mgpusim.model.errors import InputError

#: The environment variable that caps the worker processes.
ENV = "MGPUSIM_WORKERS"


def worker_count(jobs: int) -> int:
    """Worker processes for `jobs` independent jobs: the cores this process may use, at most
    `MGPUSIM_WORKERS` and `jobs`; 1 where the platform cannot fork (the workers read the
    parent's state as it stands, without pickling it)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    raw = os.environ.get(ENV, "").strip()
    if raw:
        try:
            cap = int(raw)
        except ValueError:
            cap = 0
        if cap < 1:
            raise InputError(f"{ENV}={raw!r}: expected a whole number of processes >= 1")
        cores = min(cores, cap)
    return max(1, min(cores, jobs))
