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

import heapq
from collections import deque
from typing import Any, Protocol, cast

import simpy
from simpy.core import SimTime
from simpy.events import NORMAL, PENDING, EventPriority

# looked up once: the hot paths below make an event per call
_new = object.__new__
_Timeout, _Event = simpy.Timeout, simpy.Event
_heappush = heapq.heappush

#: The environment's queue of scheduled events: (time, priority, order, event), the times in
#: integer ns (SimPy's annotation allows floats: see `Environment._times`).
Queue = list[tuple[int, EventPriority, int, simpy.Event]]


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


class StreamProcess(simpy.Process):
    """SimPy's Process with a cheaper resume, for the model's streams (a resume per event).

    A generator waits in one of two ways. It yields the event (SimPy's way): the process
    resumes it with SimPy's steps for a succeeded event, without marking the process active
    (nothing asks `env.active_process`) or making a bound method per wait. Or, on the hot path,
    it appends :attr:`resume_direct` (its own `send`, called from C: no Python frame between
    the event and the generator) to the event's callbacks itself and yields nothing; it then
    never returns (a return would raise out of the callback) but calls :meth:`finish` and
    stops at a last yield. The events and their order are the same either way. (An exception
    raised in such a generator goes straight out of `env.run()`, not through the process event;
    and a failed event it waits on is raised by the run loop: none is defused.)"""

    def __init__(self, env: simpy.Environment, generator: Any):
        super().__init__(env, generator)
        self.generator = generator
        #: the callback a wait appends (one bound method, made once)
        self.resume = self._resume
        #: the callback a generator that waits by itself appends (it is sent the event)
        self.resume_direct = self._send = generator.send

    def _resume(self, event: simpy.Event) -> None:
        send = self._send
        try:
            while event._ok:
                event = send(event._value)
                if event is None:  # the generator waits by itself
                    return
                callbacks = event.callbacks
                if callbacks is not None:
                    callbacks.append(self.resume)
                    self._target = event
                    return
        # the generator ended or failed, as in SimPy's Process._resume: not swallowed, the
        # process event fails with it and the run raises it
        except BaseException as exc:  # noqa: BLE001
            self._ended(exc)
            return
        simpy.Process._resume(self, event)  # a failed event: thrown into the generator

    def finish(self) -> None:
        """The generator that waits by itself is done: the process event succeeds (as when a
        SimPy generator returns)."""
        self._ended(StopIteration())

    def _ended(self, exc: BaseException) -> None:
        """The generator returned (StopIteration) or raised: the process event succeeds with
        its value or fails with the exception, as in SimPy's `_resume`."""
        self._target = None  # type: ignore[assignment]
        if isinstance(exc, StopIteration):
            self._ok, self._value = True, exc.args[0] if exc.args else None
        else:
            self._ok, self._value = False, exc
        self.env.schedule(self)


class Environment(simpy.Environment):
    """SimPy's environment, with the queue of scheduled events its own, so that what is
    pending can be read (:meth:`pending`) without SimPy's private state, at no cost per event.

    It processes events in SimPy's order (time, then priority, then scheduling order) with a
    cheaper queue for the commonest kind: an event triggered for now at normal priority (a
    stream's inputs met, a transfer done) goes to a first-in first-out list, not the heap.
    Every such event was scheduled after every heap event due at the same time with normal
    priority (those were scheduled at an earlier time), and urgent ones go first anyway: so
    the heap's events due now run first, then the list in order, then time moves on.

    Its clock is integer ns (`now: int`), which the channels and executors rely on, so they
    are typed with it; a plain simpy.Environment serves them too where every delay is an int
    (as in the tests)."""

    #: The clock, a plain attribute: SimPy's `now` is a property (a call on every read, and
    #: the model reads it several times per event). This class attribute shadows it, so the
    #: instance's own value is read directly; `_now`, which SimPy's code uses, is the same value.
    now: int = 0

    @property
    def _now(self) -> int:
        return self.now

    @_now.setter
    def _now(self, value: int) -> None:
        self.now = value

    def __init__(self) -> None:
        super().__init__()
        # SimPy binds `timeout`, `event`, `process`, ... to the instance only for the class's own
        # attributes (`BoundClass.bind_early`); bound here too, they cost no descriptor per call
        for name, obj in vars(simpy.Environment).items():
            if type(obj) is simpy.core.BoundClass:
                setattr(self, name, getattr(self, name))
        # (SimPy's annotations make `timeout`, `event` and `schedule` methods; at run time
        # SimPy itself sets them on the instance, BoundClass.bind_early, as done here)
        self.timeout = self._timeout  # type: ignore[method-assign]
        self.event = self._event  # type: ignore[method-assign]
        #: the plain `schedule`: timeouts and triggers schedule inline while it is the one
        #: (a caller may wrap `schedule`, e.g. to count events: they then go through it)
        self._plain = self._schedule
        self.schedule = self._plain  # type: ignore[method-assign]
        self.tracking = True
        self._now_list: deque[simpy.Event] = deque()
        #: SimPy's `_queue` (the same list) as the model fills it: every delay it schedules is
        #: integer ns, so every time in it is an int (SimPy's annotation allows floats)
        self._times = cast(Queue, self._queue)

    def _schedule(self, event: simpy.Event, priority: EventPriority = NORMAL, delay: SimTime = 0) -> None:
        """SimPy's schedule, events for now at normal priority on the list."""
        if delay or priority != NORMAL:
            heapq.heappush(self._queue, (self.now + delay, priority, next(self._eid), event))
        else:
            self._now_list.append(event)

    def _timeout(self, delay: SimTime = 0, value: Any = None) -> simpy.Timeout:
        """SimPy's Timeout, made without its constructor's call chain."""
        if delay < 0:
            raise ValueError(f"Negative delay {delay}")
        event = _new(_Timeout)
        event.env = self  # (one store each: a tuple assignment of five builds a tuple first)
        event.callbacks = []
        event._value = value
        event._delay = delay
        event._ok = True
        if self.schedule is not self._plain:  # wrapped (e.g. counted): through `schedule`
            self.schedule(event, NORMAL, delay)
        elif delay:
            _heappush(self._queue, (self.now + delay, NORMAL, next(self._eid), event))
        else:
            self._now_list.append(event)
        return event

    def _event(self) -> simpy.Event:
        """SimPy's Event (pending), made without calling its constructor."""
        event = _new(_Event)
        event.env, event.callbacks, event._value = self, [], PENDING
        return event

    def trigger(self, event: simpy.Event) -> None:
        """`event.succeed()` for an event the model made and nobody else triggers."""
        event._ok, event._value = True, None
        if self.schedule is not self._plain:
            self.schedule(event)
        else:
            self._now_list.append(event)

    def peek(self) -> Any:
        if self._now_list:
            return self.now
        return self._queue[0][0] if self._queue else simpy.core.Infinity

    def _next(self) -> simpy.Event:
        """The next event in SimPy's order (see the class doc); IndexError when none is left."""
        queue, now_list = self._times, self._now_list
        if now_list and not (queue and queue[0][0] <= self.now):
            return now_list.popleft()
        self.now, _, _, event = heapq.heappop(queue)
        return event

    def step(self) -> None:
        try:
            event = self._next()
        except IndexError:
            raise simpy.core.EmptySchedule from None
        callbacks, event.callbacks = event.callbacks, None  # type: ignore[assignment]  # (see run)
        try:
            for callback in callbacks:
                callback(event)
        except simpy.core.StopSimulation:
            event.callbacks = callbacks[callbacks.index(callback) + 1:]
            self.schedule(event, EventPriority(-1))  # (as SimPy's step: before anything else now)
            raise
        if not event._ok and not hasattr(event, "_defused"):
            exc = type(event._value)(*event._value.args)
            exc.__cause__ = event._value
            raise exc

    def run(self, until: Any = None) -> Any:
        """SimPy's run, with its step inlined when it runs to the end (`until` None, the
        engine's case): the same events in the same order, each callback called the same way,
        a failed event not defused raised the same way; one method call less per event."""
        if until is not None:
            return super().run(until)
        queue, now_list, pop, popleft = self._times, self._now_list, heapq.heappop, self._now_list.popleft
        now = self.now  # (only this loop moves the clock)
        while True:
            if now_list and not (queue and queue[0][0] <= now):
                event = popleft()
            elif queue:
                now, _, _, event = pop(queue)
                self.now = now
            else:
                return None
            # a processed event's callbacks are None (SimPy's annotation says a list; its own
            # step ignores the assignment the same way)
            callbacks, event.callbacks = event.callbacks, None  # type: ignore[assignment]
            for callback in callbacks:
                callback(event)
            if not event._ok and not hasattr(event, "_defused"):
                exc = type(event._value)(*event._value.args)
                exc.__cause__ = event._value
                raise exc

    def succeed_now(self, event: simpy.Event) -> None:
        """Trigger `event` from the last callback of the event being processed; when no other
        event is due at this instant, process it at once: the next step would pop it, so it
        runs in the same order, without a trip through the queue. (Only from a callback that
        is its event's last: anything the callback left would run after it in SimPy.)"""
        queue = self._queue
        if self._now_list or (queue and queue[0][0] <= self.now):  # (peek() <= now, inline)
            event.succeed()
            return
        event._ok, event._value = True, None
        callbacks, event.callbacks = event.callbacks, None  # type: ignore[assignment]  # (see run)
        for callback in callbacks:
            callback(event)

    def stop_tracking(self) -> None:
        """No more looks at what is pending (the fast-forward is done): :meth:`pending`
        refuses from now on."""
        self.tracking = False

    def pending(self) -> list[tuple[int, EventPriority, simpy.Event]]:
        """(time, priority, event) of every scheduled event not processed yet, in the order
        SimPy will process them (time, then priority, then scheduling order): the heap's
        events due now, the list of events for now, then the heap's later ones."""
        if not self.tracking:
            raise Unsupported("the environment stopped keeping its events")
        now = self.now
        heap = [(t, p, ev) for t, p, _eid, ev in sorted(self._times)]
        due = [entry for entry in heap if entry[0] <= now]
        return due + [(now, NORMAL, ev) for ev in self._now_list] + heap[len(due):]
