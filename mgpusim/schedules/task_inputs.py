"""The inputs a trace row lists for its task, as integer ids rather than text.

A trace row lists the task's dependencies on other frames or other devices (the `waits_for`
column, ``offset:task`` joined by ``;``), so that exporters can draw flow arrows from the trace
alone. In a many-chunk pipeline one task waits for thousands of pieces: a text label carried by
every row made memory and time grow with the square of the chunk count. Here every task of the
program has an id (its place in the templates, phase after phase) and each id its inputs as
(frame offset, input's id) pairs; the executors log the id, and the text is built from these
tables once per task of the program, only where someone reads it (a trace table, a file).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

from mgpusim.schedules.base import FrameProgram, task_device


@dataclass(frozen=True, eq=False)
class TaskInputs:
    """Ids and listed inputs of every task of a program.

    `names[i]`: task id i's name; `ids[phase]`: task name -> id in that frame phase;
    `inputs[i]`: its listed inputs as (frame offset <= 0, input task's id), in its deps' order."""

    names: tuple[str, ...]
    ids: tuple[dict[str, int], ...]
    inputs: tuple[tuple[tuple[int, int], ...], ...]

    def __len__(self) -> int:
        return len(self.names)

    def label(self, task_id: int) -> str:
        """The `waits_for` text of one task: ``offset:task`` joined by ``;`` ('' for none)."""
        return ";".join(f"{offset}:{self.names[src]}" for offset, src in self.inputs[task_id])

    @functools.cached_property
    def labels(self) -> tuple[str, ...]:
        """Every task's `waits_for` text, by id (built on first use, once)."""
        return tuple(self.label(i) for i in range(len(self.names)))

    def edge_count(self) -> int:
        """How many inputs all tasks of one period list together."""
        return sum(len(x) for x in self.inputs)


def task_inputs(program: FrameProgram) -> TaskInputs:
    """The program's ids and, per task, the dependencies its trace row lists: those on another
    frame, or on a task that runs on another device (or the host). Linear in tasks and deps."""
    period = len(program.templates)
    ids: list[dict[str, int]] = []
    names: list[str] = []
    for tasks in program.templates:
        ids.append({t.name: len(names) + j for j, t in enumerate(tasks)})
        names.extend(t.name for t in tasks)
    device = [task_device(t) for tasks in program.templates for t in tasks]
    inputs: list[tuple[tuple[int, int], ...]] = []
    for phase, tasks in enumerate(program.templates):
        for task in tasks:
            me = ids[phase][task.name]
            listed = []
            for d in task.deps:
                src = ids[(phase + d.offset) % period][d.task]
                if d.offset or device[src] != device[me]:
                    listed.append((d.offset, src))
            inputs.append(tuple(listed))
    return TaskInputs(tuple(names), tuple(ids), tuple(inputs))


def waits_for_labels(program: FrameProgram) -> list[dict[str, str]]:
    """Per phase and task, its `waits_for` text (the Vulkan runner's trace rows carry it)."""
    table = task_inputs(program)
    return [{name: table.labels[i] for name, i in ids.items()} for ids in table.ids]
