"""Exact fast-forward: once the model's state repeats up to a shift, the rest is that repeat.

The event model is deterministic, so its future is a function of its state. At the end of
every frame (its present) the engine's whole state is written down relative to that moment
and that frame: every queue's process (where its generator stands and its locals), every
pending SimPy event (time from now, priority, order, what it will call), dependency counts,
ready and skipped instances, host wake-ups and the threads waiting for their turn to wake, the
memcpy threads and their queue, and every channel's flows (exact remaining bytes, rates,
scale). Times are written relative to now and frame numbers relative to the frame, so two
moments with equal descriptions are the same state shifted by P frames and T ns. From the
first such pair on, the run is the block between them repeated, until the end of the run comes
into view.

The run is then shortened in place: the streams stop after N' = N - kP frames, for the largest
k that keeps the end out of view at the repeat (every frame the state names is below N' - 1),
so the shortened run passes through the same states. The full run's logs (trace rows, link busy
intervals, skipped frames) are the shortened run's, with the block inserted k more times, each
shifted by P frames and T ns, and what follows shifted by k blocks (:class:`Repeat`).

The state is what the model's parts expose (:mod:`.state`): the engine's `state()` (its
streams' positions, the instances waiting, the host threads, the effects and every channel's
`state()`), and the pending events the environment keeps, each described by its callbacks
(a stream resuming, or a model :class:`~.state.Callback` saying what it will do). Nothing is
read from generator frames or SimPy's private attributes. Anything that cannot be described
exactly (an event or a callback the model does not know) stops the fast-forward for that run,
and the summary says why; it never guesses.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import simpy

from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_RECORDED_FRAMES, WHY_RECORDED
from mgpusim.sim.executors import Dedicated, Interpreter, SharedCores, SharedGpu
from mgpusim.sim.snapshot import Callback, Relative, Unsupported

if TYPE_CHECKING:
    from mgpusim.sim.engine import Engine

#: Stop looking for a repeat after this many frames (the run then simply continues, up to
#: MAX_RECORDED_FRAMES: a longer one is refused there, see :class:`Unrepeated`).
PROBE_FRAMES = 4000


class Unrepeated(Exception):
    """A run of more than MAX_RECORDED_FRAMES frames that has not fast-forwarded, where that is
    known: its fast-forward is off, or gave up (the run would keep every frame's records).
    Raised before the run goes past the frames it looks at, from inside the run where it gives
    up there; `simulate()` turns it into the user's error. Its one argument says why no repeat
    was found (positional only: SimPy re-raises a copy made from the arguments)."""


def unrepeated_error(frames: int, why: str, file: str | None = None, key: str = "schedule.frames") -> InputError:
    """The error of a run of more than MAX_RECORDED_FRAMES frames that has not fast-forwarded
    (:class:`Unrepeated`, `why` its argument), naming `key`."""
    return InputError(f"{frames:,} frames, but above {MAX_RECORDED_FRAMES:,} a run must fast-forward "
                      f"(its state must repeat) and this one did not ({why}): frame by frame it would "
                      f"keep every frame's records, more than fit in memory ({WHY_RECORDED}); give at "
                      f"most {MAX_RECORDED_FRAMES:,} frames, or a schedule whose state repeats (with the "
                      "fast-forward on)", file=file, field=key)


@dataclass
class Repeat:
    """Where the logs of a shortened run split, and how the full run repeats its block.

    Rows `[rows[0], rows[1])` of the shortened run (and likewise each channel's busy intervals
    and each skipped-frame list) were logged between the two equal states, `frames` frames and
    `ns` ns apart; the full run logs that block `copies` + 1 times, each shifted one step more,
    and the rest of the shortened run shifted by `copies` steps."""

    frames: int
    ns: int
    copies: int
    anchor_frame: int
    rows: tuple[int, int]
    busy: dict[str, tuple[int, int]] = field(default_factory=dict)
    skipped: dict[str, tuple[int, int]] = field(default_factory=dict)
    #: channels busy without a break over the whole block: their open interval's start (it
    #: does not move with the repeats)
    held_open: dict[str, int] = field(default_factory=dict)


class FastForward:
    """Watches an engine's presents, finds a repeat, shortens the run (see the module doc)."""

    def __init__(self, engine: Engine, probe_frames: int | None = None, keep_rows: bool = True):
        """`probe_frames`: frames to look for a repeat in (default PROBE_FRAMES). `keep_rows`: the
        caller wants the trace; if not, the rows the engine records for the fast-forward are
        dropped, and no longer recorded, once it gives up."""
        self.engine = engine
        self.keep_rows = keep_rows
        self.probe_frames = PROBE_FRAMES if probe_frames is None else probe_frames
        self.seen: dict[tuple, tuple[int, int, tuple]] = {}
        #: cheap keys met so far: the full description is only written for a moment whose
        #: cheap key was met before (a repeat is then found one period later than it could be)
        self.cheap: set[tuple] = set()
        self.repeat: Repeat | None = None
        self.reason = "no repeat found"
        self.active = True
        self._opid = {id(op): (i, j) for i, ops in enumerate(engine.all_ops()) for j, op in enumerate(ops)}
        # a stream resumes through its process, or through its generator where it waits by itself
        self._proc_index = {id(p): i for i, p in enumerate(engine.processes)}
        self._proc_index.update((id(p.generator), i) for i, p in enumerate(engine.processes))
        unknown = sorted({type(ex).__name__ for ex in engine.executors.values()
                          if type(ex) not in (Dedicated, Interpreter, SharedCores, SharedGpu)})
        if unknown:  # its state is not written down: a repeat could not be trusted
            self._give_up(f"executor {', '.join(unknown)} has state this fast-forward does not describe")
        if engine.refresh_period is not None:  # the refresh grid's phase is not in the state
            self._give_up("vsync (schedule.refresh_hz): presents follow the display's refresh, "
                          "whose phase the fast-forward does not describe")

    # ----- driven by the engine -----------------------------------------------------------
    def on_present(self, frame: int) -> None:
        """Frame `frame` presented: look at the state once the current process has yielded."""
        if not self.active:
            return
        if frame >= self.probe_frames:
            self._give_up(f"no repeat within the first {self.probe_frames} frames")
            return
        self.engine.env.timeout(0).callbacks.append(_Probe(self, frame))

    def look(self, frame: int) -> None:
        """Write the state down after frame `frame` presented; shorten the run at a repeat."""
        if not self.active:
            return
        key = self._cheap_key(frame)
        if key not in self.cheap:
            self.cheap.add(key)
            return
        try:
            describer = _Describer(self.engine, frame, self._opid, self._proc_index)
            sig = describer.signature()
        except Unsupported as exc:
            self._give_up(f"state not described exactly ({exc})")
            return
        now = self.engine.env.now
        marks = self._marks()
        earlier = self.seen.get(sig)
        if earlier is None:
            self.seen[sig] = (frame, now, marks)
            return
        held = _held_open(earlier, (frame, now, marks))
        if held is None:  # a channel's busy log does not repeat yet: keep looking
            self.seen[sig] = (frame, now, marks)
            return
        self._stop()
        self._shorten(earlier, (frame, now, marks), describer.max_frame, held)

    def _stop(self) -> None:
        """Look no more: forget the states seen; the environment keeps no more events."""
        self.active = False
        self.seen.clear()
        self.cheap.clear()
        self.engine.env.stop_tracking()

    def describe(self, frame: int) -> tuple:
        """The model's whole state now, relative to now and to frame `frame`: what the states
        after two presents are compared by."""
        return _Describer(self.engine, frame, self._opid, self._proc_index).signature()

    def _give_up(self, reason: str) -> None:
        self._stop()
        self.reason = reason
        if self.engine.horizon > MAX_RECORDED_FRAMES:  # it will not fast-forward now
            raise Unrepeated(reason)
        if not self.keep_rows:  # memory stays flat for the rest of a long run
            self.engine.record = False
            self.engine.rows.clear()

    def _cheap_key(self, frame: int) -> tuple:
        """A part of the state that is quick to write down: when pending events fire, and how
        many instances wait on what. Equal full states have equal cheap keys (when the same
        number of probes is pending, as in a periodic run)."""
        e, now = self.engine, self.engine.env.now
        times = tuple(sorted(t - now for t, _p, _ev in e.env.pending()))
        return (frame % e.period, times, *e.cheap_state())

    def _marks(self) -> tuple:
        e = self.engine
        return (len(e.rows), {n: len(c.busy) for n, c in e.channels.items()},
                {n: len(f) for n, f in e.skipped_frames.items()}, _open_since(e))

    def _shorten(self, first: tuple, second: tuple, max_frame: int, held: dict[str, int]) -> None:
        (f1, t1, m1), (f2, t2, m2) = first, second
        period, shift = f2 - f1, t2 - t1
        n = self.engine.horizon
        copies = max(0, (n - (max_frame + 2)) // period)
        self.reason = f"state repeats every {period} frame(s), {shift} ns, from frame {f1}"
        if copies == 0:
            return  # the end is already in view: nothing to skip
        self.engine.shorten(n - copies * period)
        busy = {name: (m1[1].get(name, 0), m2[1].get(name, 0)) for name in m2[1]}
        skipped = {name: (m1[2].get(name, 0), m2[2].get(name, 0)) for name in m2[2]}
        self.repeat = Repeat(period, shift, copies, f1, (m1[0], m2[0]), busy, skipped, held)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"used": self.repeat is not None, "why": self.reason}
        if self.repeat is not None:
            r = self.repeat
            out.update(period_frames=r.frames, period_ns=r.ns, from_frame=r.anchor_frame,
                       frames_skipped=r.copies * r.frames)
        return out


def run(engine: Engine, enabled: bool = True, record_trace: bool = True,
        progress: Callable[[int, int], None] | None = None) -> Any:
    """Run `engine` (built with record_trace=True when `enabled`), fast-forwarding if its state
    repeats; the RawResult carries the repeat and what the fast-forward did. A run of more than
    MAX_RECORDED_FRAMES frames raises :class:`Unrepeated` once it is known not to fast-forward
    (before it starts, or where the fast-forward gives up). `progress(done,
    total)`: called as frames present (about 200 times in a run), with the frames presented
    and the frames the run will simulate (fewer once a repeat is found)."""
    ff = FastForward(engine, keep_rows=record_trace) if enabled else None
    if ff is None and engine.horizon > MAX_RECORDED_FRAMES:  # (one that gave up at once raised)
        raise Unrepeated("the fast-forward is off")
    hooks: list[Callable[[int], None]] = []
    if ff is not None and ff.active:
        hooks.append(ff.on_present)
    else:
        engine.env.stop_tracking()
    if progress is not None:
        hooks.append(_reporter(engine, progress))
    if len(hooks) == 1:
        engine.on_present = hooks[0]
    elif hooks:
        def both(frame: int) -> None:
            for hook in hooks:
                hook(frame)
        engine.on_present = both
    raw = engine.run()
    raw.recorded = record_trace
    if not record_trace and (ff is None or ff.repeat is None):
        raw.rows = []  # recorded only for a fast-forward that did not happen
    if ff is not None:
        raw.repeat = ff.repeat
        raw.fast_forward = ff.summary()
    else:
        raw.fast_forward = {"used": False, "why": "off"}
    return raw


def _reporter(engine: Engine, progress: Callable[[int, int], None]) -> Callable[[int], None]:
    """A present hook that reports every ~0.5 % of the run's frames, and at its end."""
    step = max(1, engine.program.frames // 200)
    done = [0]

    def report(frame: int) -> None:
        done[0] = max(done[0], frame + 1)
        if done[0] % step == 0 or done[0] >= engine.horizon:
            progress(min(done[0], engine.horizon), engine.horizon)
    return report


def _open_since(engine: Engine) -> dict[str, int]:
    """When each busy channel's current busy interval began."""
    return {name: ch.open_since for name, ch in engine.channels.items() if ch.open_since is not None}


def _held_open(first: tuple, second: tuple) -> dict[str, int] | None:
    """Channels open at both moments: each either reopened one shift later (periodic) or never
    closed in between (held open: returned with its start). None if a log does not repeat."""
    (_f1, t1, m1), (_f2, t2, m2) = first, second
    held = {}
    for name, s2 in m2[3].items():
        s1 = m1[3].get(name)
        if s1 is None or s2 - t2 == s1 - t1:
            continue
        if s1 != s2 or m2[1].get(name, 0) != m1[1].get(name, 0):
            return None
        held[name] = s1
    return held


class _Probe(Callback):
    """The fast-forward's look at the state after a present (not part of the model's state)."""

    __slots__ = ("ff", "frame")

    def __init__(self, ff: FastForward, frame: int):
        self.ff, self.frame = ff, frame

    def __call__(self, _event: simpy.Event) -> None:
        self.ff.look(self.frame)


def _is_probe(event: simpy.Event) -> bool:
    return any(isinstance(cb, _Probe) for cb in event.callbacks or ())


class _Describer(Relative):
    """The engine's state at one moment, as a hashable value relative to now and a frame: the
    :class:`~.state.Relative` the model's parts describe themselves with."""

    def __init__(self, engine: Engine, frame: int, opid: dict, proc_index: dict):
        self.e, self.now, self.frame = engine, engine.env.now, frame
        self.opid, self.proc_index = opid, proc_index
        self.ident: dict[int, tuple] = {}
        self.objs: dict[int, int] = {}
        self.max_frame = frame

    # ----- relative values ---------------------------------------------------------------
    def f(self, frame: int) -> int:
        if frame > self.max_frame:
            self.max_frame = frame
        return frame - self.frame

    def t(self, time: int) -> int:
        return time - self.now

    def key(self, key: tuple[int, str]) -> tuple[int, str]:
        return (self.f(key[0]), key[1])

    def op(self, op: Any) -> tuple[int, int]:
        return self.opid[id(op)]

    def part(self, part: tuple) -> tuple:
        frame, op, size, state = part
        index = self.objs.setdefault(id(state), len(self.objs))
        return ("part", self.f(frame), self.opid[id(op)], size, index, state[0])

    def event(self, ev: Any) -> Any:
        if ev is None:
            return None
        tag = self.ident.get(id(ev))
        if tag is not None:
            return tag
        if isinstance(ev, simpy.Event) and ev.processed:
            return ("processed",)
        raise Unsupported(f"an event the engine does not track: {ev!r}")

    # ----- the whole state ---------------------------------------------------------------
    def signature(self) -> tuple:
        queue = [(t, p, ev) for t, p, ev in self.e.env.pending() if not _is_probe(ev)]
        self._name_events(queue)
        return (tuple(self._entry(t, p, ev) for t, p, ev in queue), self.e.state(self))

    def _name_events(self, queue: list) -> None:
        for i, (_t, _p, event) in enumerate(queue):
            self.ident[id(event)] = ("q", i)
            for cb in event.callbacks or ():
                done = cb.done if isinstance(cb, Callback) else None
                if done is not None:
                    self.ident.setdefault(id(done), ("fixed", i))
        for name, ev in self.e.named_events(self):
            self.ident.setdefault(id(ev), name)

    def _entry(self, time: int, priority: int, event: simpy.Event) -> tuple:
        if isinstance(event, simpy.Process):
            return ("process-end", self.proc_index[id(event)])
        return (self.t(time), int(priority), tuple(self._callback(cb) for cb in event.callbacks or ()))

    def _callback(self, cb: Any) -> tuple:
        if isinstance(cb, Callback):
            return cb.state(self)
        owner = getattr(cb, "__self__", None)
        if owner is not None and id(owner) in self.proc_index:  # a stream resuming
            return ("resume", self.proc_index[id(owner)])
        raise Unsupported(f"a callback {cb!r}")
