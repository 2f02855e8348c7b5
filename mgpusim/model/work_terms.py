"""Work terms: what a pass of each kind does, in the units its cost is linear in.

Why apart from the cost model: the profile checks its cost keys against these terms
(`ns_per_<term>`), and the cost model reads the profile; the terms sit below both.
"""
from __future__ import annotations

from typing import Callable

from mgpusim.model.geometry import Placement, coverage
from mgpusim.model.scene import PassSpec

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
    # blended billboards of a fixed size in the world: each covers a fixed share of the view, so
    # the fragments a particle shades grow with the view's pixels (`particle_pixel`)
    "particle_render": lambda s, px, g: {"particle": s.param("particles") * g, "pixel": px,
                                         "particle_pixel": s.param("particles") * g * px},
    # A pass known only by a measured or estimated time on a reference GPU (e.g. the DX12 case
    # study's passes); the GPU's ns_per_reference_ns scales it (1 if the profile has no entry).
    "timed": lambda s, px, g: {"reference_ns": s.param("duration_ms") * 1e6 * g},
    # A pass measured in a profiler capture (`mgpusim frame import`): `gpu_ms` on the capture's
    # GPU when it drew `pixels` pixels and all of the geometry. Its `pixel_share` of that time
    # scales with the pixels a schedule gives it (a sort-first tile, a half-eye view), the rest
    # with its geometry share (a sort-last share): a pass that shades pixels splits by tiles, one
    # that transforms geometry by objects.
    "captured": lambda s, px, g: {"reference_ns": s.param("gpu_ms") * 1e6 * (
        (1.0 - s.param("pixel_share")) * g + s.param("pixel_share") * px / max(s.param("pixels"), 1.0))},
}

#: Pass kinds known by a stated time on a reference GPU rather than measured work: a profile
#: without their costs runs them at `reference_ns` / speed, and calibration never fits them.
REFERENCE_KINDS = ("timed", "captured")


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
    "captured": ("gpu_ms", "pixels", "pixel_share"),
}
COMMON_PARAMS = ("output_bytes",)

#: Bounds of parameters narrower than any work amount's: (kind, parameter) -> (min, max).
PARAM_BOUNDS: dict[tuple[str, str], tuple[float, float]] = {
    ("captured", "pixel_share"): (0.0, 1.0),
    ("captured", "pixels"): (1.0, float(2 ** 32)),
}

#: The parameters a scene's pass of each kind must give: without them its work would silently be
#: 0 (a mesh with no triangles). The schedules' own passes (composites, present) set theirs.
REQUIRED_PARAMS: dict[str, tuple[str, ...]] = {
    "fragment_loop": ("iterations",),
    "mesh": ("triangles",),
    "filter": ("iterations",),
    "particle_update": ("particles",),
    "particle_render": ("particles",),
    "timed": ("duration_ms",),
    "captured": ("gpu_ms", "pixels", "pixel_share"),
}

#: Terms a pass kind adds where the schedule says where the pass draws (a :class:`Placement`):
#: a mesh's triangles that reach the view (setup, binning), the sum of their linear sizes in
#: pixels (blocks their edges cross) and the fragments they cover (:mod:`.geometry`). A profile
#: without their coefficients keeps the older mesh model (triangles drawn and view pixels).
PLACED_TERMS: dict[str, tuple[str, ...]] = {
    "mesh": ("visible_triangle", "triangle_edge", "fragment"),
}

#: On CPU-emulated GPUs, the terms of a pass kind whose work runs on the thread that executes
#: the command buffer, not on the rasterizer threads: llvmpipe's draw module shades, clips and
#: culls every triangle and sets it up there (Mesa's `draw` and `lp_setup`), and only the
#: binned triangles go on to its rasterizer threads. The calibration fits these terms' cores
#: apart from the rest of the pass where its pairs of passes mix them differently.
QUEUE_THREAD_TERMS: dict[str, tuple[str, ...]] = {"mesh": ("triangle",)}

#: Terms whose coefficient a profile may lack: a profile calibrated before the term was
#: modelled keeps its older model (the term costs nothing there). The placed terms, and a
#: particle draw's fragments (`particle_pixel`).
UNPRICED_OK: dict[str, tuple[str, ...]] = {**PLACED_TERMS, "particle_render": ("particle_pixel",)}


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


def pass_work(spec: PassSpec, pixels: float, geometry_share: float = 1.0,
              place: Placement | None = None) -> dict[str, float]:
    """A pass's work terms; `place` (where it draws) adds the kind's placed terms."""
    work = WORK_TERMS[spec.kind](spec, pixels, geometry_share)
    for term, param in OPTIONAL_TERMS.get(spec.kind, ()):
        if param in spec.params:
            work[term] = spec.param(param) * geometry_share
    if place is not None and spec.kind == "mesh":
        seen = coverage(place.mesh_view(int(spec.param("triangles")), spec.option("shape"),
                                        spec.option("cull")))
        work.update(visible_triangle=seen.triangles, triangle_edge=seen.edge,
                    fragment=seen.fragments)
    return work
