"""The processes one `mgpusim advise` runs its work on, started once for all its stages, the
progress of a stage over the tasks handed to them, and the garbage collector's settings while
the command runs (:func:`fewer_collections`).

Why one set for the whole command: each stage (the analytic level, even pacing, full fidelity,
the assumed shares, the timelines) used to start processes of its own, whose caches (the frame
as loaded, its profiles, the last options' programs) began cold, and each stage had to end
before the next began. With one set, work whose inputs are known is queued behind the work
still running (the even pacing of AFR behind the rest of the analytic level, the timelines
beside the assumed shares), so a worker waits only where the next work needs every result.
"""
from __future__ import annotations

from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import AbstractContextManager, contextmanager
from typing import Any, Callable, Iterable, Iterator, TypeVar

from mgpusim.io import collector

T = TypeVar("T")
#: `progress(stage, done, total)`: how far a stage has come (a command draws it).
Progress = Callable[[str, int, int], None]
#: Allocations between the cyclic garbage collector's young-generation runs while a command
#: searches (Python's default: 700). Why: with the default, the collector took 11-15 % of the
#: 20-pass frame's CPU in one process, most of it going over the same long-lived young objects
#: again; at this threshold 4-7 %, for about 20 MB more memory at the peak (the garbage itself
#: is the same).
GC_THRESHOLD = 50_000


def fewer_collections() -> AbstractContextManager[None]:
    """The cyclic garbage collector run less often (:data:`GC_THRESHOLD`), and what is loaded
    so far (modules, the frame) frozen out of its runs, in this process and the workers forked
    from it, until the block ends (:func:`mgpusim.io.collector.fewer_collections`). For a
    command's process: a library caller keeps Python's settings."""
    return collector.fewer_collections(GC_THRESHOLD)


class Workers:
    """`count` worker processes, started at the first task and kept until :meth:`close`
    (a context manager). One worker: every task runs here when it is handed in, in order."""

    def __init__(self, count: int):
        self.count = max(1, int(count))
        self._pool: ProcessPoolExecutor | None = None

    def submit(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        """`fn(*args)` on a worker (tasks start in the order they are handed in)."""
        if self.count > 1:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(max_workers=self.count)
            return self._pool.submit(fn, *args)
        done: Future[T] = Future()
        try:
            done.set_result(fn(*args))
        except Exception as exc:  # noqa: BLE001 - handed back as a worker's error would be
            done.set_exception(exc)
        return done

    def close(self) -> None:
        """Stop the workers (tasks not started are dropped: only an error leaves any)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextmanager
def workers_of(workers: int | Workers) -> Iterator[Workers]:
    """`workers` as a set of processes: a set given is used as it is (its owner closes it), a
    count makes one that is closed on leaving the block."""
    if isinstance(workers, Workers):
        yield workers
        return
    with Workers(workers) as made:
        yield made


class Tally:
    """How far one stage has come: the options of its tasks done out of `total` (or of those
    handed in, where more), reported by the caller that waits for them as each task
    ends (or as it is handed in, where it ran here). Why only then: the stages' tasks run side
    by side, and a bar is drawn for the stage the command is waiting on."""

    def __init__(self, progress: Progress | None, stage: str, total: int = 0):
        self.progress, self.stage = progress, stage
        self.total, self.added, self.done = total, 0, 0
        self.started = False
        self.pending: dict[Future, int] = {}

    def add(self, task: Future, size: int) -> None:
        """A task of `size` options joins the stage."""
        self.added += size
        self.total = max(self.total, self.added)
        self.pending[task] = size
        if task.done():  # it ran here as it was handed in: the stage is under way
            if not self.started and self.progress is not None:
                self.progress(self.stage, self.done, self.total)
            self._count()

    def wait(self, tasks: Iterable[Future]) -> None:
        """Until every one of `tasks` (this stage's) is done, reporting each of the stage's
        tasks that ends meanwhile."""
        tasks = list(tasks)
        self._count(always=True)
        while any(task in self.pending for task in tasks):
            wait(list(self.pending), return_when=FIRST_COMPLETED)
            self._count()

    def _count(self, always: bool = False) -> None:
        ended = [task for task in self.pending if task.done()]
        for task in ended:
            self.done += self.pending.pop(task)
        if self.progress is not None and (ended or always):
            self.started = True
            self.progress(self.stage, self.done, self.total)
