"""The task builders (mgpusim.sim.ops): one set of rules for the engine, the analytic level and
the replay, and the analytic level built without an engine."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from mgpusim import load_experiment
from mgpusim.model.costs import CostModel
from mgpusim.model.errors import ScheduleError
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import CopyTask, CpuTask, Dep, PassTask, QueueRef
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.program import build_program
from mgpusim.sim import engine as engine_module
from mgpusim.sim.analytic import UNSHARED, Analytic
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.engine import Engine
from mgpusim.sim.executors import make_executors, task_cores
from mgpusim.sim.ops import OpBuilder
from mgpusim.sim.snapshot import Environment
from tests.conftest import profile_dict

ROOT = Path(__file__).resolve().parents[1]


def _labels(ops) -> list[list[tuple]]:
    """What the analytic level reads off each op: its task, duration, cap, bytes, gap, labels
    and its channel's bandwidth."""
    return [[(op.name, op.duration, op.cap, op.nbytes, op.gap, op.device, op.engine, op.waits_for,
              op.is_present, None if op.channel is None else op.channel.bandwidth) for op in phase]
            for phase in ops]


@pytest.mark.parametrize("name", ["sort_first_tc1.toml", "afr_temporal_tc1.toml",
                                  "pipelining_miniengine_pcie3x8.toml", "h100_x2/xr.toml"])
def test_the_engine_runs_the_ops_a_bare_builder_makes(name):
    """The engine's ops are those of a builder on an environment that never runs (what the
    analytic level uses), task for task, with the unshared effects."""
    exp = load_experiment(ROOT / "experiments" / name, {"schedule.frames": 20})
    program, costs = build_program(exp), CostModel(exp.profile)
    effects = choose_effects(program, exp.profile) - UNSHARED
    engine = Engine(program, costs, effects=effects)
    env = Environment()
    bare = OpBuilder(program, costs, effects, env, make_executors(env, costs, shared=False))
    assert _labels(bare.all_ops()) == _labels(engine.all_ops())
    assert (bare.inputs.names, bare.inputs.inputs) == (engine.inputs.names, engine.inputs.inputs)
    assert list(bare.channels) == [n for n in engine.channels if n != "host.memory"]


def test_the_analytic_level_builds_no_engine(monkeypatch):
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 20})
    program = build_program(exp)

    def refused(*_args, **_kwargs):
        raise AssertionError("the analytic level built an Engine")
    monkeypatch.setattr(engine_module.Engine, "__init__", refused)
    model = Analytic(program, CostModel(exp.profile), choose_effects(program, exp.profile, "analytic"))
    assert model.phases and model.inputs is not None


def _two_chains() -> FrameProgram:
    q = QueueRef(0, "graphics")
    tasks = (PassTask("a", "update", q, "present", {}, skip_if_busy=True),
             PassTask("b", "update", q, "present", {}, skip_if_busy=True),
             PassTask("c", "copy", q, "present", {}, (Dep("a"), Dep("b")), skip_if_busy=True),
             PassTask("present", "present", q, "present", {}, (Dep("c"),)))
    return FrameProgram("two_chains", 1, 2, 0, (tasks,))


def test_the_analytic_level_still_refuses_a_follower_of_two_skip_chains():
    """As the engine does (its probe engine used to refuse it for the analytic level)."""
    costs = CostModel(parse_profile(profile_dict(), "p"))
    with pytest.raises(ScheduleError, match="two skip chains"):
        Analytic(_two_chains(), costs, frozenset())


def test_a_peer_copy_without_a_peer_is_a_schedule_error():
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 40})
    program = build_program(exp)
    copy = next(t for t in program.templates[0] if isinstance(t, CopyTask))
    broken = replace(copy, path="p2p", peer=None)
    tasks = tuple(broken if t is copy else t for t in program.templates[0])
    with pytest.raises(ScheduleError, match="names no peer"):
        Engine(replace(program, templates=(tasks,)), CostModel(exp.profile))


def test_a_cpu_task_keeps_one_core_busy():
    profile = parse_profile(profile_dict(), "p")
    assert task_cores(profile, CpuTask("work", "cpu", "main", fixed_ns=1000.0)) == 1


def test_a_copys_time_bound_is_the_exact_one():
    """check_transfer compares in integers where it can: exactly the Fraction rule, at the
    bound and one ns past it, and a float setup falls back to it."""
    from fractions import Fraction

    from mgpusim.model import limits
    from mgpusim.model.errors import TimeBoundError
    costs = CostModel(parse_profile(profile_dict(), "p.toml"))
    rate = Fraction(7, 3)  # bytes per ns
    nbytes = 3 * 10 ** 9  # 1.286e9 ns at that rate
    left = limits.MAX_TASK_NS - nbytes / rate
    for setup, refused in ((int(left), False), (int(left) + 1, True), (float(int(left)), False)):
        assert (setup + nbytes / rate > limits.MAX_TASK_NS) == refused
        if refused:
            with pytest.raises(TimeBoundError, match="one task may last"):
                costs.check_transfer("c", nbytes, rate, setup, "f")
        else:
            costs.check_transfer("c", nbytes, rate, setup, "f")
