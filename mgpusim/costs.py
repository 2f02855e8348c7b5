"""The cost model: (pass, GPU) -> duration, (bytes, path, queue) -> transfer parameters.

Costs are linear in work terms so that calibration is a least-squares fit. Durations are
computed in floating point and rounded once (half up) to integer ns where they enter the engine.
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import TYPE_CHECKING, Callable, Mapping

from . import limits as L
from .errors import InputError, TimeBoundError
from .geometry import Placement, coverage
from .scene import PassSpec

if TYPE_CHECKING:  # profile.py reads WORK_TERMS to check cost keys
    from .profile import HardwareProfile

WorkFn = Callable[[PassSpec, float, float], dict[str, float]]

#: For each pass kind: (spec, pixels, geometry_share) -> work terms (singular names).
WORK_TERMS: dict[str, WorkFn] = {
    "fragment_loop": lambda s, px, g: {"pixel": px, "pixel_iteration": px * s.param("iterations")},
    "mesh": lambda s, px, g: {"triangle": s.param("triangles") * g, "pixel": px},
    "composite_sort_first": lambda s, px, g: {"input": s.param("inputs"), "pixel": px},
    "composite_sort_last": lambda s, px, g: {"input": s.param("inputs"), "pixel": px},
    "present": lambda s, px, g: {"pixel": px},
    # a fragment loop that also samples `inputs` images at every pixel (the temporal pass, the
    # pipelining chain's passes that read other passes' outputs)
    "filter": lambda s, px, g: {"pixel": px, "pixel_iteration": px * s.param("iterations"),
                                "pixel_input": px * s.param("inputs", 1)},
    "particle_update": lambda s, px, g: {"particle": s.param("particles") * g},
    "particle_render": lambda s, px, g: {"particle": s.param("particles") * g, "pixel": px},
    # A pass known only by a measured or estimated time on a reference GPU (e.g. the DX12 case
    # study's passes); the GPU's ns_per_reference_ns scales it (1 if the profile has no entry).
    "timed": lambda s, px, g: {"reference_ns": s.param("duration_ms") * 1e6 * g},
}


#: The parameters each pass kind reads (scene.passes entries); any kind may also carry
#: `output_bytes` (what a pipelined pass hands to the next GPU). Anything else is a typo.
PASS_PARAMS: dict[str, tuple[str, ...]] = {
    "fragment_loop": ("iterations",),
    "mesh": ("triangles", "texture_bytes"),
    "composite_sort_first": ("inputs", "pixels"),
    "composite_sort_last": ("inputs", "pixels"),
    "present": (),
    "filter": ("iterations", "inputs"),
    "particle_update": ("particles",),
    "particle_render": ("particles",),
    "timed": ("duration_ms",),
}
COMMON_PARAMS = ("output_bytes",)

#: Terms a pass kind adds where the schedule says where the pass draws (a :class:`Placement`):
#: a mesh's triangles that reach the view (setup, binning), the sum of their linear sizes in
#: pixels (blocks their edges cross) and the fragments they cover (:mod:`.geometry`). A profile
#: without their coefficients keeps the older mesh model (triangles drawn and view pixels).
PLACED_TERMS: dict[str, tuple[str, ...]] = {
    "mesh": ("visible_triangle", "triangle_edge", "fragment"),
}


#: Terms a pass kind adds only where the scene gives their parameter, so that profiles and
#: measure tables without it keep the older model: (term, parameter), times the geometry share.
#: A textured mesh samples `texture_bytes` of decoded texture per frame (its GPU's geometry
#: share of them), one texture byte at `ns_per_texture_byte`.
OPTIONAL_TERMS: dict[str, tuple[tuple[str, str], ...]] = {
    "mesh": (("texture_byte", "texture_bytes"),),
}


def work_terms(kind: str) -> tuple[str, ...]:
    """The work terms a pass kind produces (its cost keys are ns_per_<term>)."""
    return (tuple(WORK_TERMS[kind](PassSpec(kind, kind), 1.0, 1.0)) + PLACED_TERMS.get(kind, ())
            + tuple(term for term, _ in OPTIONAL_TERMS.get(kind, ())))


def ns(value: float) -> int:
    """Round a non-negative duration to integer ns, half up (the one rounding rule)."""
    return int(math.floor(value + 0.5))


def round_half_up(x: Fraction) -> int:
    return math.floor(x + Fraction(1, 2))


def gbps_fraction(gbps: float) -> Fraction:
    """Bytes per ns as an exact fraction of the decimal the user wrote."""
    return Fraction(repr(float(gbps)))


def pass_work(spec: PassSpec, pixels: float, geometry_share: float = 1.0,
              place: Placement | None = None) -> dict[str, float]:
    """A pass's work terms; `place` (where it draws) adds the kind's placed terms."""
    work = WORK_TERMS[spec.kind](spec, pixels, geometry_share)
    for term, param in OPTIONAL_TERMS.get(spec.kind, ()):
        if param in spec.params:
            work[term] = spec.param(param) * geometry_share
    if place is not None and spec.kind == "mesh":
        seen = coverage(place.mesh_view(int(spec.param("triangles"))))
        work.update(visible_triangle=seen.triangles, triangle_edge=seen.edge,
                    fragment=seen.fragments)
    return work


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
            if kind == "timed":
                return work.get("reference_ns", 0.0) / gpu.speed
            raise InputError(f"no cost coefficients for pass kind {kind!r} on {gpu.name}",
                             file=self.profile.source, field=where)
        total = cost.fixed_ns
        for term, amount in work.items():
            if amount == 0:
                continue
            coef = cost.ns_per.get(term)
            if coef is None:
                if term in PLACED_TERMS.get(kind, ()):
                    continue
                if kind == "timed" and term == "reference_ns":
                    coef = 1.0
                else:
                    raise InputError(f"missing coefficient for work term {term!r}",
                                     file=self.profile.source, field=f"{where}.ns_per_{term}")
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
        MAX_TASK_NS, so that simulated time fits int64; `field` is the rate's profile field."""
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
