"""A fluid bandwidth channel (a PCIe link direction, a peer link, host memory).

Concurrent transfers share the channel's bandwidth max-min fairly, each limited by its own
cap (a copy queue's rate, a memcpy thread's speed). Rates are recomputed only when a transfer
starts or ends, as SimGrid's flow model does. Remaining bytes are exact fractions, so no error
accumulates; a transfer completes at its exact finish time rounded half up to the nanosecond,
and all transfers that round to the same nanosecond complete together.

A transfer that has the channel to itself takes the fast path: its end is computed once in
integer arithmetic and no solver runs. Only when a second transfer arrives does the channel
switch to the fluid solver (same answer: the solo case is the solver's one-flow case).
Arrivals in the same nanosecond are settled together, so a burst of N transfers costs one
rate computation, not N.
"""
from __future__ import annotations

from fractions import Fraction

import simpy

from ..costs import round_half_up

_HALF = Fraction(1, 2)


class _Flow:
    __slots__ = ("remaining", "cap", "rate", "done", "start", "nbytes")

    def __init__(self, nbytes: int, cap: Fraction | None, done: simpy.Event, start: int):
        self.nbytes, self.cap, self.done, self.start = nbytes, cap, done, start
        self.remaining: Fraction | None = None  # set when the fluid solver takes over
        self.rate = Fraction(0)


class Channel:
    """One direction of one link; `busy` records the intervals with at least one transfer."""

    def __init__(self, env: simpy.Environment, name: str, bandwidth: Fraction):
        if bandwidth <= 0:
            raise ValueError(f"channel {name}: bandwidth must be > 0")
        self.env, self.name, self.bandwidth = env, name, bandwidth
        self.flows: list[_Flow] = []
        self.busy: list[tuple[int, int]] = []
        self.max_concurrent = 0
        self.solver_runs = 0
        self._t = 0
        self._gen = 0
        self._busy_since = 0
        self._settle_pending = False
        self._solo_rate: dict[Fraction | None, tuple[Fraction, int, int]] = {}

    def transfer(self, nbytes: int, cap: Fraction | None = None) -> simpy.Event:
        """An event that fires when `nbytes` have crossed the channel."""
        done = self.env.event()
        if nbytes <= 0:
            return done.succeed()
        now = self.env.now
        flow = _Flow(nbytes, cap, done, now)
        if not self.flows:
            self._start_solo(flow, now)
            return done
        if len(self.flows) == 1 and self.flows[0].remaining is None:
            self._to_fluid(self.flows[0], now)
        self._advance()
        flow.remaining = Fraction(nbytes)
        self.flows.append(flow)
        self.max_concurrent = max(self.max_concurrent, len(self.flows))
        if not self._settle_pending:
            self._settle_pending = True
            self._gen += 1  # any planned wake-up is stale now
            self.env.timeout(0).callbacks.append(self._settle)
        return done

    # ----- one transfer alone: integer arithmetic ----------------------------------------
    def _start_solo(self, flow: _Flow, now: int) -> None:
        rate, num, den = self._rate_parts(flow.cap)
        flow.rate = rate
        self.flows.append(flow)
        self.max_concurrent = max(self.max_concurrent, 1)
        self._busy_since = now
        end = now + (2 * flow.nbytes * den + num) // (2 * num)  # round half up of bytes / rate
        self._gen += 1
        gen = self._gen
        self.env.timeout(end - now).callbacks.append(lambda _e: self._solo_done(gen))

    def _rate_parts(self, cap: Fraction | None) -> tuple[Fraction, int, int]:
        parts = self._solo_rate.get(cap)
        if parts is None:
            rate = self.bandwidth if cap is None or cap >= self.bandwidth else cap
            parts = self._solo_rate[cap] = (rate, rate.numerator, rate.denominator)
        return parts

    def _solo_done(self, gen: int) -> None:
        if gen != self._gen:
            return
        flow = self.flows.pop()
        self.busy.append((self._busy_since, self.env.now))
        flow.done.succeed()

    def _to_fluid(self, flow: _Flow, now: int) -> None:
        flow.remaining = flow.nbytes - flow.rate * (now - flow.start)
        self._t = now

    # ----- several transfers: the fluid solver -------------------------------------------
    def _advance(self) -> None:
        now = self.env.now
        dt = now - self._t
        if dt:
            for flow in self.flows:
                flow.remaining -= flow.rate * dt
            self._t = now

    def _reshare(self) -> None:
        """Max-min fair shares with per-flow caps (water-filling)."""
        self.solver_runs += 1
        left, flows = self.bandwidth, sorted(self.flows, key=_cap_key)
        for k, flow in enumerate(flows):
            fair = left / (len(flows) - k)
            flow.rate = fair if flow.cap is None or flow.cap >= fair else flow.cap
            left -= flow.rate

    def _settle(self, _event=None) -> None:
        """Complete the flows due now, share the bandwidth anew and plan the next wake-up."""
        self._settle_pending = False
        self._advance()
        self._reshare()
        finished = [f for f in self.flows if f.remaining < f.rate * _HALF]
        if finished:
            self.flows = [f for f in self.flows if f.remaining >= f.rate * _HALF]
            for flow in finished:
                flow.done.succeed()
            if not self.flows:
                self.busy.append((self._busy_since, self.env.now))
            self._reshare()
        self._plan()

    def _plan(self) -> None:
        self._gen += 1
        if not self.flows:
            return
        finish = min(self._t + f.remaining / f.rate for f in self.flows)
        wake = max(round_half_up(finish), self.env.now)
        gen = self._gen
        self.env.timeout(wake - self.env.now).callbacks.append(lambda _e: gen == self._gen and self._settle())


def _cap_key(flow: _Flow) -> tuple[int, Fraction]:
    return (1, Fraction(0)) if flow.cap is None else (0, flow.cap)
