"""Checks of a measured trace against the program it ran, shared by the runner tests."""
from __future__ import annotations

import pandas as pd

from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim.simulation import simulate


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


def assert_runs_the_simulators_tasks(exp: Experiment, measured: pd.DataFrame) -> None:
    """The runner executed the schedule's own FrameProgram: the same (frame, device, engine,
    step, task) rows as the simulator, and every dependency ended before its consumer began."""
    def keys(trace: pd.DataFrame) -> set[tuple]:
        gpu = trace[trace["device"] != "host"]
        return set(map(tuple, gpu[["frame", "device", "engine", "step", "task"]].to_numpy()))
    assert keys(measured) == keys(simulate(exp).trace)
    assert_dependencies_honoured(build_program(exp), measured)
