"""Scenes: resolution, bytes per pixel and the passes of a frame with their work.

A pass's parameters (iterations, triangles, particles, duration_ms, output_bytes, ...) are
kept as given; :func:`mgpusim.model.work_terms.pass_work` turns them, with the pixels and geometry share a
schedule assigns to a GPU, into the work terms the cost coefficients multiply.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Mapping

from mgpusim.model import limits as L
from mgpusim.model.geometry import PASS_OPTIONS, Placement
from mgpusim.model.toml_checks import Table, did_you_mean, show_value


@dataclass(frozen=True)
class PassSpec:
    name: str
    kind: str
    params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    #: The scene passes whose outputs this pass reads: earlier passes in this frame, or itself or
    #: a later pass (their output of the previous frame: a temporal input). Schedules that move
    #: outputs between GPUs wait only for what is read (pipelining's consumer_waits = "reads").
    reads: tuple[str, ...] = ()
    #: Options that are names (a mesh's `shape` and `cull`; geometry.PASS_OPTIONS), as given.
    options: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    def param(self, key: str, default: float = 0.0) -> float:
        return float(self.params.get(key, default))

    def option(self, key: str) -> str:
        """The named option `key` as given, else its default (the first name it takes)."""
        return self.options.get(key) or PASS_OPTIONS[self.kind][key][0]


@dataclass(frozen=True)
class Section:
    """A part of the data set that a GPU holds whole (a terrain tile, a statue): its geometry
    and its textures as decoded in GPU memory (compressed files grow when decoded)."""

    name: str
    geometry_bytes: int
    texture_bytes: int

    @property
    def bytes(self) -> int:
        return self.geometry_bytes + self.texture_bytes


@dataclass(frozen=True)
class Scene:
    width: int
    height: int
    passes: tuple[PassSpec, ...]
    color_bytes_per_pixel: int = 4
    depth_bytes_per_pixel: int = 2
    #: Resident data that sort-last splits between GPUs (geometry + textures), bytes.
    dataset_bytes: int = 0
    #: Whole objects the geometry is made of (sort-last gives each GPU whole objects);
    #: 0 = geometry that splits into any fraction.
    objects: int = 0
    #: The data set by section (then `dataset_bytes` is their sum and `objects` their count).
    sections: tuple[Section, ...] = ()

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def whole_frame(self) -> Placement:
        """A pass that draws the whole frame, all of the geometry, with the mono camera."""
        return Placement((self.width, self.height))

    @property
    def color_bytes(self) -> int:
        return self.pixels * self.color_bytes_per_pixel

    @property
    def depth_bytes(self) -> int:
        return self.pixels * self.depth_bytes_per_pixel


def parse_scene(t: Table, pass_params: Mapping[str, tuple[str, ...]],
                common_params: tuple[str, ...] = (),
                required: Mapping[str, tuple[str, ...]] | None = None,
                bounds: Mapping[tuple[str, str], tuple[float, float]] | None = None) -> Scene:
    """The [scene] table; `pass_params` maps each pass kind to the parameters it reads (a
    parameter it does not read is a typo: refused with the closest name), `required` to those
    it must be given, `bounds` (kind, parameter) to a narrower range than any work amount's.
    Every pass may list the passes it `reads`."""
    passes = []
    names: set[str] = set()
    tables = t.tables("passes")
    every = [pt.data.get("name") for pt in tables]
    known_names = frozenset(n for n in every if isinstance(n, str))  # a set: 10^5 passes read fast
    for pt in tables:
        name = pt.get("name", str)
        if name in names:
            raise pt.error("name", f"duplicate pass name {name!r}")
        names.add(name)
        kind = pt.get("kind", str, choices=pass_params.keys())
        reads = _reads(pt, every, known_names)
        named = PASS_OPTIONS.get(kind, {})
        known = (*pass_params[kind], *named, *common_params)
        params, options = {}, {}
        for key in pt.rest():
            if key in named:
                options[key] = pt.get(key, str, choices=named[key])
                continue
            if key not in known:
                raise pt.error(key, f"unknown parameter of a {kind} pass{did_you_mean(key, known)} "
                                    f"(it takes {', '.join(known)})")
            low, high = (bounds or {}).get((kind, key), (0, L.MAX_WORK))
            params[key] = pt.get(key, float, minimum=low, maximum=high,
                                 why="" if (kind, key) in (bounds or {}) else L.WHY_WORK)
        missing = [key for key in (required or {}).get(kind, ()) if key not in params]
        if missing:
            raise pt.error(missing[0], f"missing: a {kind} pass needs {' and '.join(missing)} "
                                       f"(its work is 0 without)")
        pt.finish()
        passes.append(PassSpec(name, kind, MappingProxyType(params), reads, MappingProxyType(options)))
    sections = _sections(t) if t.has("sections") else ()
    side: dict[str, Any] = {"minimum": 1, "maximum": L.MAX_SIDE, "why": L.WHY_IMAGE}
    per_pixel: dict[str, Any] = {"maximum": L.MAX_BYTES_PER_PIXEL, "why": L.WHY_IMAGE}
    scene = Scene(
        width=t.get("width", int, **side),
        height=t.get("height", int, **side),
        passes=tuple(passes),
        color_bytes_per_pixel=t.get("color_bytes_per_pixel", int, 4, minimum=1, **per_pixel),
        depth_bytes_per_pixel=t.get("depth_bytes_per_pixel", int, 2, minimum=0, **per_pixel),
        dataset_bytes=t.get("dataset_bytes", int, 0, minimum=0, maximum=L.MAX_BYTES, why=L.WHY_BYTES),
        objects=t.get("objects", int, 0, minimum=0, maximum=L.MAX_WORK, why=L.WHY_WORK),
        sections=sections,
    )
    t.finish()
    if sections:
        scene = _with_sections(scene, t)
    return scene


def _reads(pt: Table, names: list, known: frozenset[str]) -> tuple[str, ...]:
    """A pass's `reads`: a list of the scene's pass names (each once; `known`: those names as
    a set, for the lookup, `names` as written, for the hint)."""
    reads = pt.get("reads", list, [])
    for item in reads:
        if not isinstance(item, str) or item not in known:
            hint = did_you_mean(item, map(str, names)) if isinstance(item, str) else ""
            raise pt.error("reads", f"expected names of this scene's passes, got {show_value(item)}{hint}")
    if len(set(reads)) != len(reads):
        raise pt.error("reads", f"a pass is named twice in {reads!r}")
    return tuple(reads)


def temporal_reads(scene: Scene) -> list[tuple[str, str]]:
    """(pass, the pass whose previous-frame output it reads) for every read of a pass at or
    after the reader in the scene's order: what alternate-frame rendering must carry between
    GPUs."""
    order = {p.name: i for i, p in enumerate(scene.passes)}
    return [(p.name, r) for p in scene.passes for r in p.reads if order[r] >= order[p.name]]


def _sections(t: Table) -> tuple[Section, ...]:
    """`[[scene.sections]]`: name, geometry_bytes, texture_bytes (decoded)."""
    out: list[Section] = []
    for st in t.tables("sections"):
        name = st.get("name", str)
        if name in {s.name for s in out}:
            raise st.error("name", f"duplicate section name {name!r}")
        size: dict[str, Any] = {"minimum": 0, "maximum": L.MAX_BYTES, "why": L.WHY_BYTES}
        out.append(Section(name, st.get("geometry_bytes", int, **size),
                           st.get("texture_bytes", int, 0, **size)))
        st.finish()
    return tuple(out)


def _with_sections(scene: Scene, t: Table) -> Scene:
    """A sectioned data set: `dataset_bytes` is the sections' sum, `objects` their count
    (either, if also given, must agree)."""
    total, count = sum(s.bytes for s in scene.sections), len(scene.sections)
    if scene.dataset_bytes not in (0, total):
        raise t.error("dataset_bytes", f"the sections hold {total} bytes, but dataset_bytes = "
                                       f"{scene.dataset_bytes} (give one or the other)")
    if scene.objects not in (0, count):
        raise t.error("objects", f"there are {count} sections, but objects = {scene.objects} "
                                 "(a GPU holds whole sections: they are the objects)")
    if total > L.MAX_BYTES:
        raise t.error("sections", f"the sections hold {total} bytes, more than {L.MAX_BYTES} "
                                  f"({L.WHY_BYTES})")
    return replace(scene, dataset_bytes=total, objects=count)
