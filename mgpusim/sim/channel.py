"""A fluid bandwidth channel (a PCIe link direction, a peer link, host memory).

Concurrent transfers share the channel's bandwidth max-min fairly, each limited by its own
cap (a copy queue's rate, a memcpy thread's speed). Rates are recomputed only when a transfer
starts or ends, as SimGrid's flow model does. A transfer completes at its exact finish time
rounded half up to the nanosecond; transfers that round to the same nanosecond complete
together.

Exactness without floats: the solver counts bytes in units of 1/S byte, where the scale S is
a multiple of every rate's denominator and of lcm(1..n) for up to n concurrent flows. Every
fair share, every cap and every byte count is then an integer, so remaining bytes are exact,
nothing drifts, and Python's integers keep it fast. S grows (and remainders are rescaled)
when a new cap or a larger crowd of flows appears.

Transfers take the fast path while nothing is shared: one alone on the channel, or several
whose caps add up to no more than the bandwidth (each then crosses at its cap, as the solver
would give it). Each one's end is computed once and no solver runs; the first transfer that
would have to share turns the running ones into flows of the solver. Arrivals in the same
nanosecond are settled together, so a burst of N transfers costs one rate computation, not N.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable

import simpy

from mgpusim.sim.fluid import FluidChannel
from mgpusim.sim.snapshot import Callback, Environment, Relative

_ZERO = Fraction(0)
_UNCAPPED = math.inf
#: An occupant's amount (:meth:`Channel.occupy`): more than any run can use up.
OCCUPANT = 1 << 80


@dataclass(frozen=True)
class PassWork:
    """A flow's tag on an oversubscribed channel: a pass of this kind. Passes of one kind
    alone together lose nothing when their threads outnumber the cores; a `lossless` kind (its
    slowdown two at once was measured: that is its cap) loses nothing beside other work either."""

    kind: str
    lossless: bool = False


class _Flow:
    __slots__ = ("remaining", "cap", "cap_s", "rate", "done", "start", "nbytes", "solo_rate", "tag",
                 "order")

    def __init__(self, nbytes: int, cap: Fraction | None, done: simpy.Event, start: int,
                 tag: object = None):
        self.nbytes, self.cap, self.done, self.start, self.tag = nbytes, cap, done, start, tag
        self.remaining = 0  # in 1/S bytes, set when the solver takes over
        self.rate = 0  # in 1/S bytes per ns
        self.cap_s: int | None = None
        #: where the solver sorts it: its scaled cap (set with `cap_s`), uncapped ones last
        self.order: int | float = _UNCAPPED
        #: the flow's rate while it runs on the fast path (never 0), else _ZERO itself: tested
        #: by identity in the hot paths (`bool` of a Fraction is a Python call)
        self.solo_rate: Fraction = _ZERO


class Channel(FluidChannel):
    """One direction of one link; `busy` records the intervals with at least one transfer."""

    #: whether several capped transfers that fit in the bandwidth may take the fast path (not
    #: where the capacity depends on who shares the channel)
    shares_caps_freely = True

    def __init__(self, env: Environment, name: str, bandwidth: Fraction,
                 oversubscribed: Fraction | None = None):
        """`oversubscribed`: the capacity when the flows' caps add up to twice `bandwidth` or
        more; between `bandwidth` and twice it, the capacity falls linearly from `bandwidth`
        (CPU cores lose time to context switches and cache misses when threads outnumber them);
        None keeps `bandwidth`."""
        if bandwidth <= 0:
            raise ValueError(f"channel {name}: bandwidth must be > 0")
        self.env, self.name, self.bandwidth = env, name, Fraction(bandwidth)
        self.oversubscribed = Fraction(oversubscribed) if oversubscribed is not None else None
        self.flows: list[_Flow] = []
        self.busy: list[tuple[int, int]] = []
        self.max_concurrent = 0
        self._t = 0
        self._gen = 0
        self._busy_since = 0
        self._settle_pending = False
        self._solo: dict[int, tuple[Fraction | None, Fraction, int, int]] = {}
        self._epoch = 0  # fast-path ends planned before the last switch to the solver are stale
        #: how a fast-path end triggers its flow's event: the model's Environment processes it
        #: at once where nothing else is due (same order); plain SimPy's schedules it
        self._succeed: Callable[[simpy.Event], object] = getattr(env, "succeed_now", simpy.Event.succeed)
        #: how the solver triggers the events of flows it completes: the model's Environment
        #: schedules them as `succeed` does, without its check (only the channel triggers them)
        self._trigger: Callable[[simpy.Event], object] = getattr(env, "trigger", simpy.Event.succeed)
        self._crowd = 4  # flows the scale can split among exactly
        self._denoms = self.bandwidth.denominator
        if self.oversubscribed is not None:
            self._denoms = math.lcm(self._denoms, self.oversubscribed.denominator)
        self._scale = self._denoms * math.lcm(*range(1, self._crowd + 1))
        #: the bandwidth and the oversubscribed capacity (or None) x S: set with every S
        #: (:meth:`_scaled_capacity`), so a reshare reads them without a check
        self._bw_s = 0
        self._over_s: int | None = None
        self._scaled_capacity()
        #: the one callback every settle of this channel gets (it holds nothing else)
        self._settle_cb = Settle((self,))

    def transfer(self, nbytes: int, cap: Fraction | None = None, tag: object = None) -> simpy.Event:
        """An event that fires when `nbytes` have crossed the channel. `tag`: what the flow is
        (a channel whose capacity depends on who shares it reads it; see GpuChannel)."""
        env = self.env
        done = env.event()
        if nbytes <= 0:
            return done.succeed()
        now = env.now
        flow = _Flow(nbytes, cap, done, now, tag)
        flows = self.flows
        # (_fits says no at once while the solver shares the channel: not asked then)
        if not flows or (flows[0].solo_rate is not _ZERO and self._fits(flow)):
            self._start_solo(flow, now)
            return done
        if flows[0].solo_rate is not _ZERO:  # the fast path ends here: the solver takes every flow
            self._epoch += 1
            for running in flows:
                self._to_fluid(running, now)
        dt = now - self._t  # (_advance, inline)
        if dt:
            for running in flows:
                running.remaining -= running.rate * dt
            self._t = now
        flows.append(flow)
        # (_fit_scale, inline: S grows only for a cap's new denominator or a larger crowd)
        denominator = 1 if cap is None else cap.denominator
        if len(flows) > self._crowd or self._denoms % denominator:
            self._grow_scale(denominator)
        flow.remaining = nbytes * self._scale
        if len(flows) > self.max_concurrent:
            self.max_concurrent = len(flows)
        if not self._settle_pending:
            self._settle_pending = True
            self._gen += 1  # any planned wake-up is stale now
            env.timeout(0).callbacks.append(self._settle_cb)
        return done

    def occupy(self, cap: Fraction, tag: object = None) -> object:
        """A flow that takes its fair share (at most `cap`) until :meth:`release`, with no
        amount of its own: work whose time is known (a measured pass, replayed) but whose
        load still slows the channel's other flows. Returns the handle to release."""
        self.transfer(OCCUPANT, cap, tag)
        return self.flows[-1]

    def release(self, flow: object) -> None:
        """The occupant `flow` (from :meth:`occupy`) leaves; the others share anew."""
        assert isinstance(flow, _Flow)
        if flow.solo_rate is not _ZERO:  # on the fast path: it has no planned end to drop
            self.flows.remove(flow)
            if not self.flows:
                self.busy.append((self._busy_since, self.env.now))
            return
        self._advance()
        self.flows.remove(flow)
        if not self.flows:
            self._gen += 1
            self.busy.append((self._busy_since, self.env.now))
            return
        if not self._settle_pending:
            self._settle_pending = True
            self._gen += 1
            self.env.timeout(0).callbacks.append(self._settle_cb)

    # ----- the fast path: nothing shared -----------------------------------------------------
    def _fits(self, flow: _Flow) -> bool:
        """Whether `flow` joins the running transfers on the fast path: they are on it, all
        capped, and their caps with its own add up to no more than the bandwidth (max-min
        fairness then gives each its cap)."""
        cap = flow.cap
        if not self.shares_caps_freely or cap is None or self.flows[0].solo_rate is _ZERO:
            return False
        for running in self.flows:
            if running.cap is not cap:
                break
        else:  # the common case, n flows of one cap: n x cap <= bandwidth
            n = len(self.flows) + 1
            return n * cap.numerator * self.bandwidth.denominator <= self.bandwidth.numerator * cap.denominator
        total = (cap.numerator, cap.denominator)
        for running in self.flows:
            if running.cap is None:
                return False
            total = _add(total, running.cap)
        return total[0] * self.bandwidth.denominator <= self.bandwidth.numerator * total[1]

    def _start_solo(self, flow: _Flow, now: int) -> None:
        parts = self._solo.get(id(flow.cap))  # by identity: hashing a Fraction costs a modular inverse
        if parts is None or parts[0] is not flow.cap:
            rate = self.bandwidth if flow.cap is None or flow.cap >= self.bandwidth else flow.cap
            parts = self._solo[id(flow.cap)] = (flow.cap, rate, rate.numerator, rate.denominator)
        _cap, flow.solo_rate, num, den = parts
        if not self.flows:
            self._busy_since = now
        self.flows.append(flow)
        if len(self.flows) > self.max_concurrent:
            self.max_concurrent = len(self.flows)
        if flow.nbytes == OCCUPANT:
            return  # it ends when released
        end = now + (2 * flow.nbytes * den + num) // (2 * num)  # round half up of bytes / rate
        self.env.timeout(end - now).callbacks.append(_SoloDone((self, flow, self._epoch)))

    def _to_fluid(self, flow: _Flow, now: int) -> None:
        self._fit_scale(flow)
        rate_s = flow.solo_rate.numerator * (self._scale // flow.solo_rate.denominator)
        flow.remaining = flow.nbytes * self._scale - rate_s * (now - flow.start)
        flow.solo_rate = _ZERO
        self._t = now

    # ----- several transfers: the fluid solver --------------------------------------------
    def _fit_scale(self, flow: _Flow) -> None:
        """Grow S so that this flow's cap and the current crowd divide it."""
        self._grow_scale(1 if flow.cap is None else flow.cap.denominator)

    def _grow_scale(self, denominator: int) -> None:
        """Grow S so that `denominator` (of a cap or a capacity) and the current crowd divide it."""
        need_denoms = math.lcm(self._denoms, denominator)
        crowd = self._crowd
        while crowd < len(self.flows):
            crowd *= 2
        if need_denoms == self._denoms and crowd == self._crowd:
            return
        new_scale = need_denoms * math.lcm(*range(1, crowd + 1))
        new_scale = math.lcm(new_scale, self._scale)
        factor = new_scale // self._scale
        for f in self.flows:
            f.remaining *= factor
        self._denoms, self._crowd, self._scale = need_denoms, crowd, new_scale
        self._scaled_capacity()
        for f in self.flows:
            f.cap_s = None

    def _scaled_capacity(self) -> None:
        """The bandwidth and the oversubscribed capacity in 1/S bytes per ns, at the current S
        (which divides into both): once per scale, not per reshare (the Fractions' numerator
        and denominator are Python calls)."""
        scale, bw, over = self._scale, self.bandwidth, self.oversubscribed
        self._bw_s = bw.numerator * (scale // bw.denominator)
        self._over_s = None if over is None else over.numerator * (scale // over.denominator)

    def _reshare(self) -> None:
        """Max-min fair shares with per-flow caps (water-filling), all in integers: the flows
        in the order of their scaled caps (uncapped last, equal ones in the order they came),
        each at the fair split of what is left, or at its cap where that is lower."""
        flows, scale = self.flows, self._scale
        for f in flows:  # (_scale_caps, inline)
            if f.cap_s is None and f.cap is not None:
                f.cap_s = f.order = f.cap.numerator * (scale // f.cap.denominator)
        left = self._bw_s if self._over_s is None else self._left_now()
        n = len(flows)
        if n == 1:
            flow = flows[0]
            cap_s = flow.cap_s
            flow.rate = left if cap_s is None or cap_s >= left else cap_s
            return
        if n <= 3:  # (the sort and the loop below, written out: an insertion sort, stable)
            if n == 2:
                a, b = flows
                if b.order < a.order:
                    a, b = b, a
            else:
                a, b, c = flows
                if b.order < a.order:
                    a, b = b, a
                if c.order < b.order:
                    b, c = c, b
                    if b.order < a.order:
                        a, b = b, a
                cap_s = a.cap_s
                fair = left // 3  # exact: see the module docstring
                a.rate = fair if cap_s is None or cap_s >= fair else cap_s
                left -= a.rate
                a = b
                b = c
            cap_s = a.cap_s
            fair = left // 2
            a.rate = fair if cap_s is None or cap_s >= fair else cap_s
            left -= a.rate
            cap_s = b.cap_s
            b.rate = left if cap_s is None or cap_s >= left else cap_s
            return
        for k, flow in enumerate(sorted(flows, key=_by_order)):
            fair = left // (n - k)
            flow.rate = fair if flow.cap_s is None or flow.cap_s >= fair else flow.cap_s
            left -= flow.rate

    def _left_now(self) -> int:
        """What the channel delivers to the flows it has now, in 1/S bytes per ns, floored
        where an oversubscribed capacity has other denominators.

        The capacity: all of `bandwidth` while the flows' demand (the sum of their caps; an
        uncapped flow takes everything) fits it, or while they are passes of one kind alone
        (their threads take turns without loss); beyond it, less as threads of different work
        outnumber cores (context switches, each evicting the other's caches), `oversubscribed`
        from twice it, only the demand of work that is not `lossless` losing. Computed on the
        scaled integers (S divides into every cap, the bandwidth and `oversubscribed`): exactly
        floor(capacity x S), without a Fraction per reshare (the solver's hottest line)."""
        b_s, o_s = self._bw_s, self._over_s
        if o_s is None:
            return b_s
        self._scale_caps()
        demand, lossless, uncapped = 0, 0, False
        for f in self.flows:
            if f.cap_s is None:  # uncapped
                uncapped = True
                continue
            demand += f.cap_s
            if isinstance(f.tag, PassWork) and f.tag.lossless:
                lossless += f.cap_s
        if uncapped:
            demand = 2 * b_s
        if demand <= b_s:
            return b_s  # the threads fit the cores: nothing to lose
        first = self.flows[0].tag
        if isinstance(first, PassWork) and all(f.tag is first or f.tag == first for f in self.flows):
            return b_s  # one kind of pass alone: its threads take turns without loss
        excess = min(demand - b_s, b_s)
        num, den = (b_s - o_s) * excess, b_s  # the loss, x S
        if lossless:
            num, den = num * min(demand - lossless, demand), den * demand
        return b_s - (-(-num // den))

    def _scale_caps(self) -> None:
        """Each capped flow's cap in 1/S bytes per ns, for those not yet scaled at the current S."""
        scale = self._scale
        for f in self.flows:
            if f.cap is not None and f.cap_s is None:
                f.cap_s = f.order = f.cap.numerator * (scale // f.cap.denominator)

    def _settle(self, _event: object = None, shares_stand: bool = False) -> None:
        """:meth:`FluidChannel._settle`, its steps inline (`_idle`, `_advance`, `_plan`; the
        solver's hottest path): the same steps in the same order."""
        self._settle_pending = False
        flows = self.flows
        if not flows or flows[0].solo_rate is not _ZERO:
            return  # released empty (an occupant), maybe on the fast path since: nothing to share
        env = self.env
        now = env.now
        dt = now - self._t
        if dt:
            for flow in flows:
                flow.remaining -= flow.rate * dt
            self._t = now
        if not shares_stand:
            self._reshare()
        for flow in flows:
            if 2 * flow.remaining < flow.rate:  # flows end now (within half a ns): in one pass,
                trigger, left = self._trigger, []  # each one's event triggered in order
                for f in flows:
                    if 2 * f.remaining < f.rate:
                        trigger(f.done)
                    else:
                        left.append(f)
                flows = self.flows = left
                if not flows:
                    self.busy.append((self._busy_since, now))
                    self._gen += 1
                    return
                self._reshare()
                break
        self._gen += 1
        wake = None
        for f in flows:
            if f.nbytes != OCCUPANT:
                rate = f.rate
                at = (2 * f.remaining + rate) // (2 * rate)
                if wake is None or at < wake:
                    wake = at
        if wake is None:
            return  # only occupants: nothing ends until one is released
        # (the clock was advanced to now: _plan's max(self._t + wake, now) - now)
        env.timeout(wake if wake > 0 else 0).callbacks.append(Wake((self, self._gen)))

    # ----- state (for the fast-forward) -----------------------------------------------------
    @property
    def open_since(self) -> int | None:
        """When the current busy interval began (None while idle)."""
        return self._busy_since if self.flows else None

    def state(self, rel: Relative) -> tuple:
        """The flows (exact remaining bytes, rates, caps, start, what they are), the solver's
        clock while it shares, and its scale."""
        fluid = any(f.solo_rate is _ZERO for f in self.flows)
        flows = tuple((f.remaining, f.cap, f.cap_s, f.rate, rel.t(f.start), f.nbytes, f.solo_rate,
                       rel.event(f.done), f.tag) for f in self.flows)
        return (self.name, flows, rel.t(self._t) if fluid else None, self._settle_pending,
                self._crowd, self._denoms, self._scale)

    def flow_events(self) -> list[simpy.Event]:
        """The events the running flows will trigger, in order."""
        return [f.done for f in self.flows]


class Settle(Callback, tuple):
    """Settle the channel now: flows that arrived in this nanosecond share it from here.
    (The callbacks are tuples: made at C speed, a new one for every transfer.) Any channel
    with a `_settle()` and a `name` uses it (the host side of PCIe too)."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        self[0]._settle()

    def state(self, rel: Relative) -> tuple:
        return ("settle", self[0].name)


class _SoloDone(Callback, tuple):
    """(channel, flow, epoch): a transfer on the fast path ends, unless the solver took the
    channel's flows over since (a newer epoch)."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        channel, flow, epoch = self  # (Channel._solo_done, inline: a call less per transfer)
        if epoch != channel._epoch:
            return
        channel.flows.remove(flow)
        if not channel.flows:
            channel.busy.append((channel._busy_since, channel.env.now))
        channel._succeed(flow.done)  # (the timeout's only callback: at once if nothing else is due now)

    def state(self, rel: Relative) -> tuple:
        current = self[2] == self[0]._epoch
        return ("solo done", self[0].name, rel.event(self[1].done) if current else None, current)


class Wake(Callback, tuple):
    """(channel, generation): the solver's planned wake-up for the next flow due (stale once
    the generation moved on)."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        if self[1] == self[0]._gen:
            self[0]._settle(shares_stand=True)

    def state(self, rel: Relative) -> tuple:
        return ("wake", self[0].name, self[1] == self[0]._gen)


class GpuChannel(Channel):
    """The execution throughput of one physical GPU, shared by the work of its queues.

    Amounts are ns of work at full speed and the bandwidth is 1 (one ns of work per ns): a
    piece of work alone runs at full speed. With several at once each runs at the speed
    `shares_of(tags)` gives it (the tags of the flows running, sorted: their queues and kinds;
    one speed per tag, in units of its speed alone, none above 1, so that none runs faster
    than alone)."""

    shares_caps_freely = False  # the capacity depends on whose work shares the GPU

    def __init__(self, env: Environment, name: str,
                 shares_of: Callable[[tuple], tuple[Fraction, ...]]):
        super().__init__(env, name, Fraction(1))
        self._shares_of = shares_of
        #: each sorted tuple of tags met: each tag's speed, and their denominators' lcm
        self._shares: dict[tuple, tuple[dict[object, Fraction], int]] = {}

    def _reshare(self) -> None:
        """Each flow at its tag's share (exact: the scale is grown to every share's denominator)."""
        key = tuple(sorted((f.tag for f in self.flows), key=str))
        found = self._shares.get(key)
        if found is None:
            speeds = self._shares_of(key)
            found = self._shares[key] = (dict(zip(key, speeds)), math.lcm(*(s.denominator for s in speeds)))
        by_tag, denominator = found
        self._grow_scale(denominator)
        scale = self._scale
        for flow in self.flows:
            speed = by_tag[flow.tag]
            flow.rate = speed.numerator * (scale // speed.denominator)


def _add(total: tuple[int, int], value: Fraction) -> tuple[int, int]:
    """`total` (numerator, denominator) plus `value`, in integers (Fraction arithmetic would
    cost more than the rest of a transfer)."""
    num, den = total
    vn, vd = value.numerator, value.denominator
    if vd == den:
        return num + vn, den
    num, den = num * vd + vn * den, den * vd
    g = math.gcd(num, den)
    return num // g, den // g


#: the solver's sort key, read at C speed (`_Flow.order`: an int compares with the infinity of
#: an uncapped flow exactly)
_by_order = operator.attrgetter("order")


class FixedRateChannel:
    """A link direction without sharing: every transfer crosses at its own fixed rate (the
    channel's bandwidth, or its cap if lower), however many overlap. The `queues` fidelity level
    and scenes whose copies never overlap use it; `busy` and `max_concurrent` as in Channel."""

    def __init__(self, env: Environment, name: str, bandwidth: Fraction):
        if bandwidth <= 0:
            raise ValueError(f"channel {name}: bandwidth must be > 0")
        self.env, self.name, self.bandwidth = env, name, Fraction(bandwidth)
        self.busy: list[tuple[int, int]] = []
        self.max_concurrent = 0
        self.active = 0
        self._busy_since = 0
        self._rates: dict[int, tuple[Fraction | None, int, int]] = {}
        self._deliver = _Deliver((self,))  # every transfer's first callback (it holds nothing else)

    def transfer(self, nbytes: int, cap: Fraction | None = None) -> simpy.Event:
        """The transfer's own timeout: the channel's bookkeeping is its first callback, so a
        process that waits on it resumes once the channel has let the transfer go (one event
        per transfer, not two)."""
        if nbytes <= 0:
            return self.env.event().succeed()
        return self.cross(self.duration(nbytes, cap))

    def duration(self, nbytes: int, cap: Fraction | None = None) -> int:
        """ns for `nbytes` > 0 to cross at the channel's bandwidth or `cap` if lower, rounded
        half up."""
        parts = self._rates.get(id(cap))  # by identity, as Channel's fast path
        if parts is None or parts[0] is not cap:
            rate = self.bandwidth if cap is None or cap >= self.bandwidth else cap
            parts = self._rates[id(cap)] = (cap, rate.numerator, rate.denominator)
        _cap, num, den = parts
        return (2 * nbytes * den + num) // (2 * num)

    def cross(self, ns: int) -> simpy.Event:
        """A transfer that takes `ns` (from :meth:`duration`): its timeout, the channel's
        bookkeeping its first callback."""
        if not self.active:
            self._busy_since = self.env.now
        self.active += 1
        if self.active > self.max_concurrent:
            self.max_concurrent = self.active
        done = self.env.timeout(ns)
        done.callbacks.append(self._deliver)
        return done

    @property
    def open_since(self) -> int | None:
        """When the current busy interval began (None while idle)."""
        return self._busy_since if self.active else None

    def state(self, rel: Relative) -> tuple:
        """How many transfers are crossing (each one's end is a pending event of its own)."""
        return (self.name, self.active)

    def flow_events(self) -> list[simpy.Event]:
        return []


class _Deliver(Callback, tuple):
    """(channel,): a fixed-rate transfer ends (the first callback of its timeout)."""

    __slots__ = ()

    def __call__(self, _event: simpy.Event) -> None:
        channel = self[0]  # (FixedRateChannel._done, inline: a call less per transfer)
        channel.active -= 1
        if not channel.active:
            channel.busy.append((channel._busy_since, channel.env.now))

    def state(self, rel: Relative) -> tuple:
        return ("deliver", self[0].name)
