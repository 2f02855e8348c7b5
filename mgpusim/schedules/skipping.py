"""Skippable chains: the particle demo's "new wait" policy, for any schedule.

A skip_if_busy task with a same-frame dependency on another skip_if_busy task is a *follower*
(it consumes that task's output, e.g. the copies of a particle update); one without is a
*leader*. A leader is skipped when any task of its chain from an earlier frame is still
unfinished; a follower is skipped exactly when one of its skippable inputs of the same frame
was skipped. The engine asks when an instance becomes ready and tells when one finishes.
"""
from __future__ import annotations

from collections import defaultdict
from typing import Callable, Iterable

from mgpusim.model.errors import ScheduleError
from mgpusim.model.tasks import Task
from mgpusim.schedules.base import FrameProgram

Key = tuple[int, str]


class SkipChains:
    def __init__(self, program: FrameProgram, index: list[dict[str, Task]]):
        self.period = len(program.templates)
        self.skip: set[Key] = set()
        self.skipped_frames: dict[str, list[int]] = defaultdict(list)
        self._inflight: dict[str, int] = defaultdict(int)
        self._inputs: list[dict[str, tuple[str, ...]]] = []
        self._leader: list[dict[str, str]] = []
        self._chain: list[dict[str, int]] = []
        self._readers: list[dict[str, int]] = []
        self._skipped_keys: dict[Key, int] = {}  # skipped key -> followers yet to look at it
        for phase, tasks in enumerate(program.templates):
            self._group(tasks, index[phase])

    def _group(self, tasks: tuple[Task, ...], idx: dict[str, Task]) -> None:
        inputs: dict[str, tuple[str, ...]] = {}
        leader: dict[str, str] = {}
        chain: dict[str, int] = defaultdict(int)
        readers: dict[str, int] = defaultdict(int)
        for task in tasks:
            if not task.skip_if_busy:
                continue
            ins = tuple(d.task for d in task.deps if d.offset == 0 and idx[d.task].skip_if_busy)
            if len({leader[n] for n in ins}) > 1:
                raise ScheduleError(f"skippable task {task.name!r} reads the outputs of two skip "
                                    f"chains ({', '.join(sorted({leader[n] for n in ins}))}): "
                                    "one of them could skip it while the other ran")
            leader[task.name] = leader[ins[0]] if ins else task.name
            chain[leader[task.name]] += 1
            for n in ins:
                readers[n] += 1
            if ins:
                inputs[task.name] = ins
        self._inputs.append(inputs)
        self._leader.append(leader)
        self._chain.append(dict(chain))
        self._readers.append(dict(readers))

    def ready(self, key: Key, task: Task) -> None:
        """`key` has its dependencies: decide now (CPU submit time) whether it is skipped."""
        if not task.skip_if_busy:
            return
        phase = key[0] % self.period
        ins = self._inputs[phase].get(task.name)
        if ins is not None:
            if self._take_skipped(key[0], ins):
                self._set_skipped(key, phase, task.name)
        elif self._inflight[task.name] > 0:
            self._set_skipped(key, phase, task.name)
        else:
            self._inflight[task.name] += self._chain[phase][task.name]

    def finished(self, frame: int, task: Task) -> None:
        """A skippable task ran to its end: its chain has one task fewer in flight."""
        self._inflight[self._leader[frame % self.period][task.name]] -= 1

    def _take_skipped(self, frame: int, inputs: tuple[str, ...]) -> bool:
        skipped = False
        for name in inputs:
            left = self._skipped_keys.get((frame, name))
            if left is None:
                continue
            skipped = True
            if left <= 1:
                del self._skipped_keys[(frame, name)]
            else:
                self._skipped_keys[(frame, name)] = left - 1
        return skipped

    def state(self, key: Callable[[Key], Key]) -> tuple:
        """What decides which instances are skipped next (for the fast-forward): the chains in
        flight and the skipped outputs not yet read, `key` making each instance relative."""
        return (tuple(sorted((n, v) for n, v in self._inflight.items() if v)),
                tuple(sorted((key(k), v) for k, v in self._skipped_keys.items())))

    def _set_skipped(self, key: Key, phase: int, name: str) -> None:
        self.skip.add(key)
        self.skipped_frames[name].append(key[0])
        if self._readers[phase].get(name):
            self._skipped_keys[key] = self._readers[phase][name]


class GivenSkips:
    """Skips decided beforehand, not by the rule: the instances in `keys` are skipped, every
    other runs. The replay level's: a measured run's skips are facts to follow, and its
    skippable tasks keep everything else they are (a chain's leader still waits on the host for
    its inputs). The same interface as :class:`SkipChains`."""

    def __init__(self, keys: Iterable[Key]):
        self.skip: set[Key] = set(keys)
        self.skipped_frames: dict[str, list[int]] = defaultdict(list)
        for frame, name in sorted(self.skip):
            self.skipped_frames[name].append(frame)

    def ready(self, key: Key, task: Task) -> None:
        """Nothing to decide: the skips are given."""

    def finished(self, frame: int, task: Task) -> None:
        """Nothing to count."""

    def state(self, key: Callable[[Key], Key]) -> tuple:
        return (tuple(sorted(key(k) for k in self.skip)),)
