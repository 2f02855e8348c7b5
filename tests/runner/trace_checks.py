"""Checks of a measured trace against the program it ran, shared by the runner tests."""
from __future__ import annotations

import pandas as pd

from mgpusim.schedules.base import FrameProgram


def assert_dependencies_honoured(program: FrameProgram, trace: pd.DataFrame) -> None:
    """Every task of every frame started after each of its dependencies (same or earlier
    frame) ended: the runner's semaphores and fences did what the program says."""
    spans = trace.groupby(["frame", "task"]).agg(start=("start_ns", "min"), end=("end_ns", "max"))
    for frame in range(program.frames):
        for task in program.tasks(frame):
            for dep in task.deps:
                if frame + dep.offset >= 0:
                    before = spans.loc[(frame + dep.offset, dep.task), "end"]
                    assert spans.loc[(frame, task.name), "start"] >= before, (frame, task.name, dep)
