"""The fast-forward reads only the state the model exposes: the environment's pending events,
the engine's and the channels' `state()`, and callbacks that describe themselves."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest
import simpy

from mgpusim.model.costs import CostModel
from mgpusim.sim import engine as engine_module
from mgpusim.sim import fastforward
from mgpusim.sim.engine import Engine
from mgpusim.sim.simulation import build_program
from mgpusim.sim.snapshot import Environment, Unsupported
from tests.conftest import make_experiment

ROOT = Path(__file__).resolve().parents[1]
LABELS = {engine_module.DEPS, engine_module.COPY_WAKE, engine_module.TURN, engine_module.DISPATCH,
          engine_module.SUBMIT, engine_module.GAP, engine_module.BUSY_WAKE, engine_module.RUN,
          engine_module.TRANSFER}


def _engine(frames: int = 200) -> Engine:
    exp = make_experiment(gpus=2, frames=frames)
    return Engine(build_program(exp), CostModel(exp.profile))


def test_pending_lists_events_in_the_order_simpy_processes_them():
    env = Environment()
    order = []
    for name, delay in (("late", 5), ("first", 0), ("second", 0), ("middle", 3)):
        env.timeout(delay).callbacks.append(lambda _e, name=name: order.append(name))

    def proc():  # its start is an urgent event: before "first" although scheduled after it
        order.append("urgent")
        yield env.timeout(3)
        order.append("after middle")

    env.process(proc())
    listed = [ev for _t, _p, ev in env.pending()]
    assert [t for t, _p, _ev in env.pending()] == [0, 0, 0, 3, 5]
    env.run()
    assert order == ["urgent", "first", "second", "middle", "after middle", "late"]
    assert all(ev.processed for ev in listed) and env.pending() == []


def test_after_stop_tracking_pending_is_refused_and_the_run_goes_on():
    env = Environment()
    env.timeout(1)
    env.stop_tracking()
    env.timeout(2)
    with pytest.raises(Unsupported):
        env.pending()
    env.run()
    assert env.now == 2


def test_events_for_now_run_after_those_due_now_from_before_in_simpy_order():
    """The list of events for now: the same order as SimPy's own environment."""
    def trace(env: simpy.Environment) -> list[tuple[int, str]]:
        order: list[tuple[int, str]] = []

        def note(name: str):
            return lambda _e: order.append((env.now, name))

        def proc(name: str, delays: tuple[int, ...]):
            for d in delays:
                yield env.timeout(d)
                order.append((env.now, name))
                env.event().succeed().callbacks.append(note(name + " now"))
        for i, delays in enumerate(((0, 2, 0, 1), (2, 0, 1, 0), (1, 1, 0, 2))):
            env.process(proc(f"p{i}", delays))
        env.timeout(2).callbacks.append(note("t2"))
        return order
    plain, ours = simpy.Environment(), Environment()
    expected, got = trace(plain), trace(ours)
    plain.run()
    ours.run()
    assert got == expected and len(got) > 20


def test_a_stream_says_where_it_waits_and_the_engine_state_has_every_stream():
    engine = _engine()
    engine.env.run(until=5_000_000)  # mid-run: every stream waits somewhere
    assert all(st.at in LABELS for st in engine.streams)
    state = fastforward.FastForward(engine).describe(3)
    assert len(state[1][0]) == len(engine.processes)
    assert {s[0] for s in state[1][0]} <= LABELS | {"finished"}


def test_an_undescribed_callback_is_refused_not_guessed():
    engine = _engine()
    engine.env.run(until=5_000_000)
    _t, _p, event = engine.env.pending()[0]
    event.callbacks.append(lambda _e: None)  # a callback no part of the model describes
    with pytest.raises(Unsupported, match="a callback"):
        fastforward.FastForward(engine).describe(3)


def test_the_same_run_fast_forwards_when_nothing_foreign_is_pending():
    raw = fastforward.run(_engine(frames=400))
    assert raw.fast_forward["used"] is True


def test_the_fast_forward_reads_no_private_attribute_of_another_object():
    """Only `self._x` inside its own classes: nothing like `engine._pending` or `env._queue`."""
    tree = ast.parse((ROOT / "mgpusim" / "sim" / "fastforward.py").read_text())
    private = [f"line {node.lineno}: .{node.attr}" for node in ast.walk(tree)
               if isinstance(node, ast.Attribute) and node.attr.startswith("_")
               and not node.attr.startswith("__")
               and not (isinstance(node.value, ast.Name) and node.value.id == "self")]
    assert private == []


def test_the_bench_long_run_script_runs_in_a_fresh_interpreter():
    """`mgpusim bench`'s long run is a script string run in a child process: its imports are
    checked only when it runs."""
    from mgpusim.bench.model_speed import long_run
    out = long_run(frames=200)
    assert out["frames"] == 200 and out["fast_forward"]["used"] is True and out["rows"] > 0
