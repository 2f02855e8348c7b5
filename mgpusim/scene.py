"""Scenes: resolution, bytes per pixel and the passes of a frame with their work.

A pass's parameters (iterations, triangles, particles, duration_ms, output_bytes, ...) are
kept as given; :func:`mgpusim.costs.pass_work` turns them, with the pixels and geometry share a
schedule assigns to a GPU, into the work terms the cost coefficients multiply.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

from .config import Table


@dataclass(frozen=True)
class PassSpec:
    name: str
    kind: str
    params: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    def param(self, key: str, default: float = 0.0) -> float:
        return float(self.params.get(key, default))


@dataclass(frozen=True)
class Scene:
    width: int
    height: int
    passes: tuple[PassSpec, ...]
    color_bytes_per_pixel: int = 4
    depth_bytes_per_pixel: int = 2
    #: Resident data that sort-last splits between GPUs (geometry + textures), bytes.
    dataset_bytes: int = 0

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def color_bytes(self) -> int:
        return self.pixels * self.color_bytes_per_pixel

    @property
    def depth_bytes(self) -> int:
        return self.pixels * self.depth_bytes_per_pixel


def parse_scene(t: Table, known_kinds: frozenset[str]) -> Scene:
    passes = []
    names: set[str] = set()
    for pt in t.tables("passes"):
        name = pt.get("name", str)
        if name in names:
            raise pt.error("name", f"duplicate pass name {name!r}")
        names.add(name)
        kind = pt.get("kind", str, choices=known_kinds)
        params = {}
        for key, value in pt.rest().items():
            params[key] = pt.get(key, float, minimum=0)
        pt.finish()
        passes.append(PassSpec(name, kind, MappingProxyType(params)))
    scene = Scene(
        width=t.get("width", int, minimum=1),
        height=t.get("height", int, minimum=1),
        passes=tuple(passes),
        color_bytes_per_pixel=t.get("color_bytes_per_pixel", int, 4, minimum=1),
        depth_bytes_per_pixel=t.get("depth_bytes_per_pixel", int, 2, minimum=0),
        dataset_bytes=t.get("dataset_bytes", int, 0, minimum=0),
    )
    t.finish()
    return scene
