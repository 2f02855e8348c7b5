"""Worker processes: how many a command spreads independent work over, and the spreading.

A study's calibration grid and its comparisons, each independent of the others, run in forked
workers, one per core this process may use. `MGPUSIM_WORKERS` caps that number (1: everything
in this process): for a machine shared with other work, and for a test suite that already runs
one process per core (the project's runs its tests so).
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Iterator, TypeVar

from mgpusim.model.errors import InputError

#: The environment variable that caps the worker processes.
ENV = "MGPUSIM_WORKERS"

T = TypeVar("T")


def usable_cores() -> int:
    """The cores this process may use (its affinity, where the platform has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def worker_count(jobs: int) -> int:
    """Worker processes for `jobs` independent jobs: the cores this process may use, at most
    `MGPUSIM_WORKERS` and `jobs`; 1 where the platform cannot fork (the workers read the
    parent's state as it stands, without pickling it)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return 1
    cores = usable_cores()
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


def in_workers(work: Callable[..., T], jobs: list[tuple]) -> Iterator[T]:
    """`work(*job)` of every job, yielded in the jobs' order, on :func:`worker_count` forked
    workers (here, one after another, where that is 1). The workers are forked when the first
    job is submitted: module state the parent set before the call is theirs without pickling.
    The work must not depend on which process runs it (the outputs are then the same)."""
    workers = worker_count(len(jobs))
    if workers < 2:
        for job in jobs:
            yield work(*job)
        return
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        for task in [pool.submit(work, *job) for job in jobs]:
            yield task.result()
