"""What every fluid channel shares: flows that drain at their rates between two rate changes.

A fluid channel (:class:`mgpusim.sim.channel.Channel`, the host side of PCIe in
:mod:`mgpusim.sim.hostlink`) holds flows, each with bytes `remaining` and a `rate`. Between two
events nothing changes but the bytes; at an event the channel advances the bytes to now, shares
its capacity anew (the subclass's `_reshare`: integer water-filling on one channel, progressive
filling over links and the host), completes the flows due within half a nanosecond, shares
again if any remain, and plans its next wake-up (the subclass's `_plan`). This loop is written
once here; what is shared and how the wake-up is rounded belong to each channel.
"""
from __future__ import annotations

from typing import Any

from mgpusim.sim.snapshot import Environment


class FluidChannel:
    """The advance / settle loop of a fluid channel; subclasses say how flows share it."""

    env: Environment
    name: str
    flows: list[Any]
    busy: list[tuple[int, int]]
    _t: int
    _gen: int
    _busy_since: int
    _settle_pending: bool

    def _advance(self) -> None:
        """Drain every flow by its rate over the time since the last advance."""
        now = self.env.now
        dt = now - self._t
        if dt:
            for flow in self.flows:
                flow.remaining -= flow.rate * dt
            self._t = now

    def _reshare(self) -> None:
        raise NotImplementedError

    def _plan(self) -> None:
        raise NotImplementedError

    def _idle(self) -> bool:
        """Whether there is nothing for the solver to share now."""
        return not self.flows

    def _settle(self, _event: object = None, shares_stand: bool = False) -> None:
        """Complete the flows due now, share the capacity anew and plan the next wake-up.
        `shares_stand`: the planned wake-up (:class:`~.channel.Wake`), still current, so no
        flow joined or left since the shares were worked out (each such change moves the
        generation on) and they are what sharing anew would give: only the flows that end
        now change them."""
        self._settle_pending = False
        if self._idle():
            return
        self._advance()
        if not shares_stand:
            self._reshare()
        finished = [f for f in self.flows if 2 * f.remaining < f.rate]
        if finished:
            self.flows = [f for f in self.flows if 2 * f.remaining >= f.rate]
            for flow in finished:
                flow.done.succeed()
            if not self.flows:
                self.busy.append((self._busy_since, self.env.now))
                self._gen += 1
                return
            self._reshare()
        self._plan()
