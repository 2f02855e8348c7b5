"""The cost model: (pass, GPU) -> duration, (bytes, path, queue) -> transfer parameters.

Costs are linear in work terms so that calibration is a least-squares fit. Durations are
computed in floating point and rounded once (half up) to integer ns where they enter the engine.
"""
from __future__ import annotations

import functools
import math
from fractions import Fraction
from typing import Mapping

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError, TimeBoundError
from mgpusim.model.profile import HardwareProfile, PassCost
from mgpusim.model.tasks import CpuTask, HostCopyTask
from mgpusim.model.work_terms import REFERENCE_KINDS, UNPRICED_OK


def ns(value: float) -> int:
    """Round a non-negative duration to integer ns, half up (the one rounding rule)."""
    return int(math.floor(value + 0.5))


def round_half_up(x: Fraction) -> int:
    return math.floor(x + Fraction(1, 2))


@functools.lru_cache(maxsize=4096)
def gbps_fraction(gbps: float) -> Fraction:
    """Bytes per ns as an exact fraction of the decimal the user wrote. (Cached: parsing a
    decimal into a Fraction costs more than a small run's model; a Fraction is immutable.)"""
    return Fraction(repr(float(gbps)))


def term_coefficient(cost: PassCost, kind: str, term: str, source: str, where: str) -> float | None:
    """ns per unit of work `term` of a `kind` pass: the cost's coefficient, 1 for a reference
    kind's `reference_ns`, None for a term the profile may lack (:data:`UNPRICED_OK`: it costs
    nothing there); any other missing coefficient is an InputError naming it."""
    coef = cost.ns_per.get(term)
    if coef is not None:
        return coef
    if term in UNPRICED_OK.get(kind, ()):
        return None
    if kind in REFERENCE_KINDS and term == "reference_ns":
        return 1.0
    raise InputError(f"missing coefficient for work term {term!r}", file=source,
                     field=f"{where}.ns_per_{term}")


class CostModel:
    """Turns tasks into engine inputs using one hardware profile's coefficients."""

    def __init__(self, profile: HardwareProfile):
        self.profile = profile

    def pass_ns(self, device: int, kind: str, work: Mapping[str, float]) -> int:
        """A pass's duration in integer ns: its cost, rounded once and bounded."""
        where = f"gpus[{device}].costs.{kind}"
        return self._bounded(self.pass_cost_ns(device, kind, work), kind, work, where)

    def pass_cost_ns(self, device: int, kind: str, work: Mapping[str, float]) -> float:
        """A pass's cost before the one rounding: fixed + sum(coefficient x work), over the
        GPU's speed factor (callers that scale costs first, like analytic sweeps, round later)."""
        gpu = self.profile.gpus[device]
        cost = gpu.costs.get(kind)
        where = f"gpus[{device}].costs.{kind}"
        if cost is None:
            if kind in REFERENCE_KINDS:
                return work.get("reference_ns", 0.0) / gpu.speed
            raise InputError(f"no cost coefficients for pass kind {kind!r} on {gpu.name}",
                             file=self.profile.source, field=where)
        total = cost.fixed_ns
        for term, amount in work.items():
            if amount == 0:
                continue
            coef = term_coefficient(cost, kind, term, self.profile.source, where)
            if coef is not None:
                total += coef * amount
        return total / gpu.speed

    def _bounded(self, total: float, kind: str, work: Mapping[str, float], where: str) -> int:
        """`total` ns rounded, refused beyond MAX_TASK_NS (simulated time must fit int64)."""
        if not total <= L.MAX_TASK_NS:  # also catches NaN
            terms = ", ".join(f"{t}={a:.3g}" for t, a in work.items())
            raise TimeBoundError(f"a {kind} pass would take {total:.3g} ns ({terms}), more than "
                                 f"the {L.MAX_TASK_NS:.0e} ns one task may last ({L.WHY_TIME}): "
                                 "lower the pass's parameters or the coefficients",
                                 file=self.profile.source, field=where)
        return ns(total)

    def check_transfer(self, name: str, nbytes: int, rate: Fraction, setup_ns: int, field: str) -> None:
        """A copy of `nbytes` at `rate` bytes/ns (alone on its channel) must end within
        MAX_TASK_NS, so that simulated time fits int64; `field` is the rate's profile field.
        (Compared in integers, `setup + bytes x den / num` against the bound: Fraction
        arithmetic cost more than the rest of building a copy's op.)"""
        num, den = rate.numerator, rate.denominator
        exact = isinstance(setup_ns, int) and isinstance(nbytes, int)  # (else as Fraction arithmetic rounds)
        if exact and num > 0 and setup_ns * num + nbytes * den <= L.MAX_TASK_NS * num:
            return
        total = setup_ns + nbytes / rate
        if total > L.MAX_TASK_NS:
            raise TimeBoundError(f"copy {name!r} of {nbytes} bytes at {float(rate):.3g} GB/s would "
                                 f"take {float(total):.3g} ns, more than the {L.MAX_TASK_NS:.0e} ns "
                                 f"one task may last ({L.WHY_TIME})", file=self.profile.source,
                                 field=field)

    def copy_setup_ns(self, device: int, family: str, path: str, peer: int | None = None) -> int:
        """Fixed cost of a copy command plus the latency of the path it crosses."""
        gpu = self.profile.gpus[device]
        fixed = gpu.copy[family].fixed_ns if family in gpu.copy else 0
        if path in ("d2h", "h2d"):
            return fixed + gpu.link.latency_ns
        if path == "p2p":
            link = self.profile.peer(device, peer if peer is not None else -1)
            return fixed + (link.latency_ns if link else 0)
        if path == "group":  # through both GPUs' PCIe links
            other = self.profile.gpus[peer if peer is not None else device]
            return fixed + max(gpu.link.latency_ns, other.link.latency_ns)
        return fixed

    def copy_cap(self, device: int, family: str, path: str) -> Fraction | None:
        """A queue family's own rate limit for a path (None = only the channel limits it); a
        device-group copy has its queue family's peer-to-peer cap."""
        gpu = self.profile.gpus[device]
        path = "p2p" if path == "group" else path
        cap = gpu.copy[family].caps_gbps.get(path) if family in gpu.copy else None
        return gbps_fraction(cap) if cap is not None else None

    def link_bandwidth(self, device: int, path: str) -> Fraction:
        gpu = self.profile.gpus[device]
        if path == "d2d":
            return gbps_fraction(gpu.local_copy_gbps)
        return gbps_fraction(gpu.link.bandwidth_gbps(path))

    def group_bandwidth(self, src: int, dst: int) -> Fraction:
        """A device-group copy from `src` to `dst` over PCIe: the slower of the source's d2h
        and the destination's h2d rate."""
        return min(self.link_bandwidth(src, "d2h"), self.link_bandwidth(dst, "h2d"))

    def peer_bandwidth(self, a: int, b: int) -> Fraction:
        link = self.profile.peer(a, b)
        if link is None:
            raise InputError(f"no peer link between gpu{a} and gpu{b}", file=self.profile.source,
                             field="peer_links")
        return gbps_fraction(link.bandwidth_gbps)

    def host_memory_bandwidth(self) -> Fraction:
        return gbps_fraction(self.profile.host.memory_bandwidth_gbps)

    def memcpy_thread_cap(self) -> Fraction:
        return gbps_fraction(self.profile.host.memcpy_thread_gbps)

    def host_copy_cap(self, task: HostCopyTask, uncached: bool = True) -> Fraction:
        """One part's speed on its memcpy thread: the thread's, or where the copy reads
        uncached memory (and `uncached`, the uncached_reads effect, is on) the slower
        `host.uncached_read_gbps`."""
        cap = self.memcpy_thread_cap()
        if uncached and task.uncached and self.profile.host.uncached_read_gbps:  # read only if it applies
            cap = min(cap, gbps_fraction(self.profile.host.uncached_read_gbps))
        return cap

    def cpu_task_ns(self, task: CpuTask, frame_work: bool = True) -> int:
        """A CPU task's time: its own cost, plus (`frame_work`, the host_frame_work effect)
        `host.thread_start_ns` per thread it starts and `host.record_ns` per command buffer
        it records, rounded half up once."""
        host = self.profile.host
        extra = (task.threads * host.thread_start_ns + task.command_buffers * host.record_ns
                 if frame_work else 0)
        return ns(task.cost_ns + extra)


def overlap_efficiency(alone_a: float, alone_b: float, together: float) -> float:
    """The overlap efficiency `e` that the model's rule gives for two pieces of work of
    `alone_a` and `alone_b` ns that take `together` ns from the first start to the last end
    when started at once: both run at e/2 until the shorter ends, the rest alone, so
    together = 2 min / e + |a - b| and e = 2 min(a, b) / (together - |a - b|); for equal
    pieces (a + b) / together. Kept within (0, 2] (2: no slowdown at all)."""
    short, gap = min(alone_a, alone_b), abs(alone_a - alone_b)
    if short <= 0:
        raise ValueError("overlap_efficiency: both pieces of work must take time")
    shared = together - gap
    return 2.0 if shared <= short else min(2.0, 2.0 * short / shared)
