"""The replay level: the model's timeline run on a measured run's own task durations.

Why: a prediction's error mixes two things, the cost model (how long each pass and copy takes)
and the timeline (dependencies, queues, copies, hand-offs, overlap: where each task starts).
A noisy machine moves the first from run to run, not the second. Replaying every task with the
duration the run measured for it, frame by frame, leaves only the timeline to be wrong: a replay
error is the timeline's, on any machine.

What the replay keeps from the model: the schedule's tasks and dependencies, each queue's order,
the host's hand-offs (submit and dispatch delays), the queues' idle gaps, vsync. What it takes
from the run: how long each task ran. Effects that only stretch a task's duration (link and host
memory sharing, copy caps, a shared executor or GPU) are already in the measured durations, so
the replay leaves them out; on CPU-emulated GPUs the host's cores stay, occupied by the measured
work, so that the host threads' own work (waking, submitting) competes with it as it did. A
skippable task (the particle update under "new wait") is skipped where the run skipped it, and
only there. Every part of a host copy takes the copy's duration (the run's longest part).
Another task the run did not measure in some frame takes its median over the run's other
frames; one it never measured is costed by the model.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Mapping

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.tasks import QueueRef
from mgpusim.results.summary import Result, build_result
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program, on_queues, run_config
from mgpusim.sim import fastforward
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.engine import Engine
from mgpusim.sim.executors import measured_executors

#: Effects whose whole action is to change a task's duration: measured durations hold them.
#: (On CPU-emulated GPUs the replay keeps the host's cores, which the measured work occupies:
#: the host threads' own work competes with it, :class:`mgpusim.sim.executors.MeasuredCores`.)
DURATION_EFFECTS = frozenset({"link_sharing", "host_memory_sharing", "copy_engine_caps",
                              "shared_executor", "shared_gpu"})

#: (frame, task name) -> measured ns.
Durations = Mapping[tuple[int, str], int]


def unrolled(program: FrameProgram, frames: int) -> FrameProgram:
    """`program` over `frames` frames with one template per frame, so that every frame's task
    can carry a duration of its own (the engine costs a task once per template). Whole periods
    of the program's templates: a dependency on an earlier frame wraps around to the template
    of the same phase."""
    period = len(program.templates)
    count = -(-frames // period) * period
    return replace(program, frames=frames, templates=tuple(program.tasks(f) for f in range(count)))


def replay(exp: Experiment, durations: Durations, frames: int,
           queues: Mapping[QueueRef, QueueRef] | None = None) -> Result:
    """Run `exp`'s schedule for `frames` frames with each task taking its measured duration
    (`durations`; see the module doc for tasks without one), the tasks of the queues in `queues` on the
    queue the run used (:func:`mgpusim.schedules.program.on_queues`). Same input, same result.
    The engine's builder turns each measured duration into its task's op
    (:meth:`mgpusim.sim.ops.OpBuilder.measured_op`); the rest of the timeline is the model's."""
    if frames < 1:
        raise InputError("the measured run has no frames to replay", field="frames")
    program = unrolled(on_queues(build_program(exp), queues or {}), frames)
    skipped = skipped_in_run(program, durations)
    effects = choose_effects(program, exp.profile) - DURATION_EFFECTS
    costs = CostModel(exp.profile)
    pool = (lambda env: measured_executors(env, costs)) if exp.profile.host.gpus_share_cpu else None
    engine = Engine(program, costs, record_trace=True, effects=effects, executors=pool,
                    durations=filled(program, durations), skips=skipped)
    try:
        raw = fastforward.run(engine, enabled=False, record_trace=True)
    except fastforward.Unrepeated as exc:  # (a measured run of over 10^6 frames)
        raise fastforward.unrepeated_error(frames, exc.args[0], exp.file, key="frames") from None
    result = build_result(raw, program.warmup_frames, run_config(exp, program))
    result.summary.update(fidelity="replay", modelled_effects=sorted(effects), fast_forward=raw.fast_forward)
    return result


def skipped_in_run(program: FrameProgram, durations: Durations) -> set[tuple[int, str]]:
    """The skippable instances the run did not run (no measured duration): the replay skips
    exactly these, where the run's skip rule decided."""
    return {(f, t.name) for f in range(program.frames) for t in program.tasks(f)
            if t.skip_if_busy and (f, t.name) not in durations}


def filled(program: FrameProgram, durations: Durations) -> dict[tuple[int, str], int]:
    """Every (frame, task) of the program that the run measured in at least one frame: its own
    duration, else the median of its measured ones (the upper median: an integer)."""
    by_task: dict[str, list[int]] = {}
    for (_, name), ns in durations.items():
        by_task.setdefault(name, []).append(int(ns))
    medians = {name: sorted(v)[len(v) // 2] for name, v in by_task.items()}
    out: dict[tuple[int, str], int] = {}
    for frame in range(program.frames):
        for task in program.tasks(frame):
            took = durations.get((frame, task.name))
            if took is None:
                took = medians.get(task.name)
            if took is not None:
                out[(frame, task.name)] = int(took)
    return out
