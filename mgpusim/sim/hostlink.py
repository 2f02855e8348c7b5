"""The host side of PCIe: copies of several GPUs in one direction share the host's capacity.

Every GPU has its own link, but the host's root complex and memory take only so much in one
direction at once (4x H100: one GPU alone copies to the host at 52 GB/s, four at once 30 GB/s
each, 120 GB/s in all). Under the host_pcie effect every copy of that direction crosses two
resources, its GPU's link and the host channel, and the copies share both max-min fairly: the
progressive filling of a flow network (raise every unfrozen flow's rate together; a resource
that fills, or a flow that reaches its cap, freezes its flows; repeat). One GPU alone, or
copies whose links together stay under the host capacity, cross exactly as on their links.

Rates, remaining bytes and capacities are exact fractions (bytes per ns, bytes): a transfer
completes at its exact finish time rounded half up to the nanosecond, as on a Channel, and
transfers due in the same nanosecond complete together. Rates are recomputed only when a
transfer starts or ends; arrivals in one nanosecond are settled together.
"""
from __future__ import annotations

from fractions import Fraction

import simpy

from mgpusim.sim.channel import Settle, Wake
from mgpusim.sim.fluid import FluidChannel
from mgpusim.sim.snapshot import Environment, Relative


class _Flow:
    __slots__ = ("link", "remaining", "cap", "rate", "done", "start", "nbytes")

    def __init__(self, link: str, nbytes: int, cap: Fraction | None, done: simpy.Event, start: int):
        self.link, self.nbytes, self.cap, self.done, self.start = link, nbytes, cap, done, start
        self.remaining = Fraction(nbytes)
        self.rate = Fraction(0)


class HostLinkChannel(FluidChannel):
    """One direction of PCIe for every GPU: the GPUs' links (`link(name, bandwidth)` adds one)
    and the host's capacity behind them. `busy` records the intervals with at least one
    transfer on any of the links."""

    def __init__(self, env: Environment, name: str, capacity: Fraction):
        if capacity <= 0:
            raise ValueError(f"channel {name}: capacity must be > 0")
        self.env, self.name, self.capacity = env, name, Fraction(capacity)
        self.links: dict[str, Fraction] = {}
        self.flows: list[_Flow] = []
        self.busy: list[tuple[int, int]] = []
        self.max_concurrent = 0
        #: the most links crossed at once (the host capacity binds only from two)
        self.max_links = 0
        self._t = 0
        self._gen = 0
        self._busy_since = 0
        self._settle_pending = False

    def port(self, link: str, bandwidth: Fraction) -> "LinkPort":
        """The channel as one GPU's link of `bandwidth` sees it (what a copy crosses)."""
        if bandwidth <= 0:
            raise ValueError(f"link {link}: bandwidth must be > 0")
        self.links.setdefault(link, Fraction(bandwidth))
        return LinkPort(self, link)

    def transfer(self, link: str, nbytes: int, cap: Fraction | None = None) -> simpy.Event:
        """An event that fires when `nbytes` have crossed `link` and the host channel."""
        done = self.env.event()
        if nbytes <= 0:
            return done.succeed()
        self._advance()
        if not self.flows:
            self._busy_since = self.env.now
        self.flows.append(_Flow(link, nbytes, None if cap is None else Fraction(cap), done, self.env.now))
        self.max_concurrent = max(self.max_concurrent, len(self.flows))
        self.max_links = max(self.max_links, len({f.link for f in self.flows}))
        if not self._settle_pending:
            self._settle_pending = True
            self._gen += 1  # any planned wake-up is stale now
            self.env.timeout(0).callbacks.append(Settle((self,)))
        return done

    # ----- the solver (its loop: FluidChannel._settle) ------------------------------------
    def _reshare(self) -> None:
        """Progressive filling over the links and the host channel, with per-flow caps."""
        share(self.flows, self.links, self.capacity)

    def _plan(self) -> None:
        """Wake at the next flow's end, rounded half up to the nanosecond."""
        self._gen += 1
        wake = min(self._t + int(f.remaining / f.rate + Fraction(1, 2)) for f in self.flows)
        wake = max(wake, self.env.now)
        self.env.timeout(wake - self.env.now).callbacks.append(Wake((self, self._gen)))

    # ----- state (for the fast-forward) -------------------------------------------------
    @property
    def open_since(self) -> int | None:
        """When the current busy interval began (None while idle)."""
        return self._busy_since if self.flows else None

    def state(self, rel: Relative) -> tuple:
        """The flows (link, exact remaining bytes, rate, cap, start, size), the solver's clock."""
        flows = tuple((f.link, f.remaining, f.rate, f.cap, rel.t(f.start), f.nbytes, rel.event(f.done))
                      for f in self.flows)
        return (self.name, flows, rel.t(self._t) if self.flows else None, self._settle_pending)

    def flow_events(self) -> list[simpy.Event]:
        """The events the running flows will trigger, in order."""
        return [f.done for f in self.flows]


def share(flows: list[_Flow], links: dict[str, Fraction], capacity: Fraction) -> None:
    """Max-min fair rates for `flows`, each crossing its link and the host channel of
    `capacity`, each at most its cap: raise all unfrozen rates together to the lowest level at
    which a resource fills or a cap is reached, freeze the flows held there, repeat."""
    if len(flows) == 1:  # alone: the least of the host's capacity, its link and its cap
        f = flows[0]
        level = min(capacity, links[f.link])
        f.rate = level if f.cap is None or f.cap > level else f.cap
        return
    for f in flows:
        f.rate = Fraction(0)
    free = list(flows)
    host_left = capacity
    link_left = dict(links)
    while free:
        on_link: dict[str, int] = {}
        for f in free:
            on_link[f.link] = on_link.get(f.link, 0) + 1
        level = host_left / len(free)
        for name, n in on_link.items():
            level = min(level, link_left[name] / n)
        level = min([level] + [f.cap for f in free if f.cap is not None])
        full_links = {name for name, n in on_link.items() if link_left[name] == level * n}
        host_full = host_left == level * len(free)
        still = []
        for f in free:
            if host_full or f.link in full_links or (f.cap is not None and f.cap <= level):
                f.rate = level
                host_left -= level
                link_left[f.link] -= level
            else:
                still.append(f)
        free = still


class LinkPort:
    """One GPU's link of a HostLinkChannel: `transfer` as a Channel's."""

    __slots__ = ("channel", "link")

    def __init__(self, channel: HostLinkChannel, link: str):
        self.channel, self.link = channel, link

    def transfer(self, nbytes: int, cap: Fraction | None = None) -> simpy.Event:
        return self.channel.transfer(self.link, nbytes, cap)
