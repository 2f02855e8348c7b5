"""What the model's parts expose so that the fast-forward can write their state down.

The fast-forward (:mod:`.fastforward`) compares the whole model's state at two presents, each
written relative to its moment and frame. It reads no generator frames and no private state
of SimPy: the engine, every channel, the skip chains and the busy_wake effect each describe
themselves through a `state(rel)` method, given a :class:`Relative` that turns times, frames,
events and tasks into values relative to the moment. What is waiting to happen is read from
:class:`Environment`, which keeps the events it schedules, and every callback the model puts on
an event is a :class:`Callback` that says what it will do.
"""
from __future__ import annotations

from typing import Any, Protocol

import simpy


class Unsupported(Exception):
    """A part of the state that cannot be described exactly (the fast-forward then stops)."""


class Relative(Protocol):
    """Values relative to the moment described: `t(time)` ns from now, `f(frame)` frames from
    the presented frame, `key((frame, task))`, `event(ev)` (which pending event, or processed),
    `op(op)` (which task of the program), `part(part)` (a host copy's part)."""

    def t(self, time: int) -> int: ...

    def f(self, frame: int) -> int: ...

    def key(self, key: tuple[int, str]) -> tuple[int, str]: ...

    def event(self, ev: Any) -> Any: ...

    def op(self, op: Any) -> Any: ...

    def part(self, part: tuple) -> tuple: ...


class Callback:
    """A callback the model appends to a SimPy event: called with the event, and able to say
    what it will do when it runs (`state`). `done`: an event it will trigger, if any, named
    after the pending event that holds this callback."""

    __slots__ = ()
    done: simpy.Event | None = None

    def __call__(self, event: simpy.Event) -> None:
        raise NotImplementedError

    def state(self, rel: Relative) -> tuple:
        raise NotImplementedError


class Environment(simpy.Environment):
    """SimPy's environment that also keeps a list of the events it schedules (through the
    public `schedule`), so that what is pending can be read without SimPy's private queue.
    Keeping it costs a little per event: the fast-forward stops it once it is done."""

    def __init__(self) -> None:
        super().__init__()
        # SimPy binds `timeout`, `event`, `process`, ... to the instance only for the class's own
        # attributes (`BoundClass.bind_early`); bound here too, they cost no descriptor per call
        for name, obj in vars(simpy.Environment).items():
            if type(obj) is simpy.core.BoundClass:
                setattr(self, name, getattr(self, name))
        self._scheduled: list[tuple[int, int, int, simpy.Event]] = []
        self._seq = 0
        self.tracking = True

    def schedule(self, event: simpy.Event, priority: int = simpy.events.NORMAL, delay: int = 0) -> None:
        super().schedule(event, priority, delay)
        if self.tracking:
            self._seq += 1
            self._scheduled.append((self.now + delay, priority, self._seq, event))

    def succeed_now(self, event: simpy.Event) -> None:
        """Trigger `event` from the last callback of the event being processed; when no other
        event is due at this instant, process it at once: the next step would pop it, so it
        runs in the same order, without a trip through the queue. (Only from a callback that
        is its event's last: anything the callback left would run after it in SimPy.)"""
        if self.peek() <= self.now:
            event.succeed()
            return
        event._ok, event._value = True, None
        callbacks, event.callbacks = event.callbacks, None
        for callback in callbacks:
            callback(event)

    def stop_tracking(self) -> None:
        """Keep no more events (after the last look at what is pending): SimPy's own
        `schedule` serves from now on, at no cost."""
        self.tracking = False
        self._scheduled = []
        self.schedule = simpy.Environment.schedule.__get__(self)  # type: ignore[method-assign]

    def pending(self) -> list[tuple[int, int, simpy.Event]]:
        """(time, priority, event) of every scheduled event not processed yet, in the order
        SimPy will process them (time, then priority, then scheduling order)."""
        if not self.tracking:
            raise Unsupported("the environment stopped keeping its events")
        self._scheduled = [entry for entry in self._scheduled if not entry[3].processed]
        return [(t, p, ev) for t, p, _seq, ev in sorted(self._scheduled, key=lambda e: e[:3])]
