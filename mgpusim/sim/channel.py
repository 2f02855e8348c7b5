"""A fluid bandwidth channel (a PCIe link direction, a peer link, host memory).

Concurrent transfers share the channel's bandwidth max-min fairly, each limited by its own
cap (a copy queue's rate, a memcpy thread's speed). Rates are recomputed only when a transfer
starts or ends, as SimGrid's flow model does. Remaining bytes are exact fractions, so no error
accumulates; a transfer completes at its exact finish time rounded half up to the nanosecond,
and all transfers that round to the same nanosecond complete together.
"""
from __future__ import annotations

from fractions import Fraction

import simpy

from ..costs import round_half_up

_HALF = Fraction(1, 2)


class _Flow:
    __slots__ = ("remaining", "cap", "rate", "done")

    def __init__(self, remaining: Fraction, cap: Fraction | None, done: simpy.Event):
        self.remaining, self.cap, self.rate, self.done = remaining, cap, Fraction(0), done


class Channel:
    """One direction of one link; `busy` records the intervals with at least one transfer."""

    def __init__(self, env: simpy.Environment, name: str, bandwidth: Fraction):
        if bandwidth <= 0:
            raise ValueError(f"channel {name}: bandwidth must be > 0")
        self.env, self.name, self.bandwidth = env, name, bandwidth
        self.flows: list[_Flow] = []
        self.busy: list[tuple[int, int]] = []
        self.max_concurrent = 0
        self._t = 0
        self._gen = 0
        self._busy_since = 0

    def transfer(self, nbytes: int, cap: Fraction | None = None) -> simpy.Event:
        """An event that fires when `nbytes` have crossed the channel."""
        done = self.env.event()
        if nbytes <= 0:
            return done.succeed()
        self._advance()
        if not self.flows:
            self._busy_since = self.env.now
        self.flows.append(_Flow(Fraction(nbytes), cap, done))
        self.max_concurrent = max(self.max_concurrent, len(self.flows))
        self._reshare()
        self._schedule()
        return done

    def _advance(self) -> None:
        now = self.env.now
        dt = now - self._t
        if dt:
            for flow in self.flows:
                flow.remaining -= flow.rate * dt
            self._t = now

    def _reshare(self) -> None:
        """Max-min fair shares with per-flow caps (water-filling)."""
        left, flows = self.bandwidth, sorted(self.flows, key=_cap_key)
        for k, flow in enumerate(flows):
            fair = left / (len(flows) - k)
            flow.rate = fair if flow.cap is None or flow.cap >= fair else flow.cap
            left -= flow.rate

    def _schedule(self) -> None:
        self._gen += 1
        if not self.flows:
            return
        finish = min(self._t + f.remaining / f.rate for f in self.flows)
        wake = max(round_half_up(finish), self.env.now)
        gen = self._gen
        self.env.timeout(wake - self.env.now).callbacks.append(lambda _e: self._wake(gen))

    def _wake(self, gen: int) -> None:
        if gen != self._gen:
            return  # rates changed since this wake-up was planned
        self._advance()
        now = self.env.now
        finished = [f for f in self.flows if f.remaining < f.rate * _HALF]
        self.flows = [f for f in self.flows if f.remaining >= f.rate * _HALF]
        for flow in finished:
            flow.done.succeed()
        if not self.flows:
            self.busy.append((self._busy_since, now))
        self._reshare()
        self._schedule()


def _cap_key(flow: _Flow) -> tuple[int, Fraction]:
    return (1, Fraction(0)) if flow.cap is None else (0, flow.cap)
