"""The mesh every mesh pass draws, its camera, and what a view of it covers (pure numpy).

Why here and not in the Vulkan package: the cost model needs the same geometry the runner
draws. A rasterizer pays per triangle it sets up and per fragment it covers, not per triangle
of the scene: a view that sees half the mesh (an XR half-eye, a sort-first strip) culls the
triangles outside it, and a sort-last share that faces the camera covers more pixels than one
that does not. :func:`coverage` projects the scene's own triangles with the runner's camera
and counts what a view rasterizes, so the mesh cost can be fitted on it and extrapolates to
views, shares and sizes it was not measured at.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Mapping

import numpy as np

from mgpusim.model.errors import InputError

#: Half the distance between the eyes of the stereo camera (scene units; the torus is ~1.7 wide).
EYE_HALF_SEPARATION = 0.08
#: Above this many triangles, coverage is measured on a torus of this many and scaled (the
#: covered area does not depend on the tessellation; a triangle's size goes as 1/sqrt(T)).
COVERAGE_SAMPLE_TRIANGLES = 200_000


def even_split(total: int, parts: int) -> list[int]:
    """`total` in `parts` equal integer shares, the last taking the remainder: the rule for
    sort-first tiles, XR half-eye views, chunked copies and host-copy parts alike."""
    base = total // parts
    return [base] * (parts - 1) + [total - base * (parts - 1)]


def torus_mesh(triangles: int, radius: float = 0.6, tube: float = 0.25) -> np.ndarray:
    """A tessellated torus of exactly `triangles` triangles: float32 (3*T, 6) = position, normal."""
    if triangles <= 0:
        raise InputError(f"must be positive, got {triangles}", field="triangles")
    quads = math.ceil(triangles / 2)
    major = max(3, math.ceil(math.sqrt(quads * 4)))
    minor = max(3, math.ceil(quads / major))
    u = np.arange(major + 1) * (2 * np.pi / major)
    w = np.arange(minor + 1) * (2 * np.pi / minor)
    uu, ww = np.meshgrid(u, w, indexing="ij")
    normal = np.stack([np.cos(uu) * np.cos(ww), np.sin(uu) * np.cos(ww), np.sin(ww)], -1)
    centre = np.stack([np.cos(uu) * radius, np.sin(uu) * radius, np.zeros_like(uu)], -1)
    vert = np.concatenate([centre + tube * normal, normal], -1).astype(np.float32)
    a, b = vert[:-1, :-1], vert[1:, :-1]
    c, d = vert[1:, 1:], vert[:-1, 1:]
    tris = np.stack([np.stack([a, b, c], -2), np.stack([a, c, d], -2)], -3)  # (M, m, 2, 3, 6)
    return tris.reshape(-1, 3, 6)[:triangles].reshape(-1, 6)


def mvp(eye: int | None = None) -> np.ndarray:
    """The fixed perspective camera looking at the tilted torus (row-major float32 4x4); `eye`
    0 / 1 moves it half the eye separation to the left / right (a stereo pair), None = mono."""
    f, near, far = 1.0 / math.tan(math.radians(30)), 0.5, 10.0
    proj = np.array([[f, 0, 0, 0], [0, f, 0, 0], [0, 0, far / (near - far), near * far / (near - far)],
                     [0, 0, -1, 0]], dtype=np.float32)
    view = np.eye(4, dtype=np.float32)
    view[2, 3] = -2.5
    if eye is not None:
        view[0, 3] = EYE_HALF_SEPARATION if eye == 0 else -EYE_HALF_SEPARATION
    tilt = np.eye(4, dtype=np.float32)
    ang = math.radians(35)
    tilt[1:3, 1:3] = [[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]]
    return (proj @ view @ tilt).astype(np.float32)


@dataclass(frozen=True)
class MeshView:
    """What one mesh pass draws: triangles [first, first + count) of the scene's torus of
    `triangles`, seen by camera `eye`, into pixels `rect` = (x, y, w, h) of a `frame` (w, h)."""

    triangles: int
    frame: tuple[int, int]
    rect: tuple[int, int, int, int] | None = None
    first: int = 0
    count: int | None = None
    eye: int | None = None

    def key(self) -> tuple:
        rect = self.rect or (0, 0, *self.frame)
        count = self.triangles - self.first if self.count is None else self.count
        return (self.triangles, self.frame, rect, self.first, count, self.eye)


@dataclass(frozen=True)
class Placement:
    """Where a pass of a schedule draws: pixels `rect` (x, y, w, h; None = all) of a `frame`
    (w, h), geometry share `share` = (k, n) (sort-last GPU k of n draws triangles
    [T k // n, T (k + span) // n), the runner's rule; `span` > 1: several whole objects of n),
    camera `eye` (None = mono)."""

    frame: tuple[int, int]
    rect: tuple[int, int, int, int] | None = None
    share: tuple[int, int] = (0, 1)
    eye: int | None = None
    span: int = 1

    @property
    def pixels(self) -> int:
        """The pixels the pass renders: its rectangle's, or the whole frame's."""
        w, h = self.rect[2:] if self.rect else self.frame
        return w * h

    def mesh_view(self, triangles: int) -> MeshView:
        k, n = self.share
        first = triangles * k // n
        return MeshView(triangles, self.frame, self.rect, first,
                        triangles * (k + self.span) // n - first, self.eye)


#: Where a measured mesh draws: `whole`, or `;`-separated items `share=K/N` (sort-last share
#: K of N), `eye=left|right` (the stereo camera), `column=K/N` (an XR view's columns), `row=K/N`
#: (a sort-first strip), K counted from 0. The fit then sees triangles outside the view culled,
#: and shares that cover more or fewer pixels than others.
MESH_PLACE: dict[str, str] = {"place": "whole"}
#: The stereo camera's eyes by name (index 0 / 1 of :func:`mvp`).
EYES = {"left": 0, "right": 1}


def mesh_placement(p: Mapping[str, Any]) -> Placement:
    """The placement a measured mesh's `width`, `height` and `place` describe (with the
    schedules' own splitting rules)."""
    w, h, text = int(p["width"]), int(p["height"]), str(p.get("place", "whole"))
    parts = {"share": (0, 1), "column": (0, 1), "row": (0, 1)}
    eye = None
    for item in ([] if text == "whole" else text.split(";")):
        key, _, value = (s.strip() for s in item.partition("="))
        if key == "eye" and value in EYES:
            eye = EYES[value]
        elif key in parts and _fraction(value, w if key == "column" else h if key == "row" else None):
            k, n = value.split("/")
            parts[key] = (int(k), int(n))
        else:
            raise InputError(f"expected 'whole' or items share=K/N, eye=left|right, column=K/N, "
                             f"row=K/N (0 <= K < N) separated by ';', got {text!r}", field="place")
    cols, rows = even_split(w, parts["column"][1]), even_split(h, parts["row"][1])
    c, r = parts["column"][0], parts["row"][0]
    rect = (sum(cols[:c]), sum(rows[:r]), cols[c], rows[r])
    return Placement((w, h), rect, parts["share"], eye)


def _fraction(value: str, side: int | None) -> bool:
    """Whether `value` is K/N with 0 <= K < N (and N <= `side` where a side is split)."""
    k, sep, n = value.partition("/")
    if not (sep and k.isdigit() and n.isdigit()):
        return False
    return 0 <= int(k) < int(n) and (side is None or int(n) <= side)


@dataclass(frozen=True)
class Coverage:
    """What a view rasterizes: triangles that reach its rectangle, the pixels they cover
    (overdraw included: no culling, every layer is rasterized) and the sum of their linear
    sizes in pixels (sqrt of each one's area: a rasterizer's per-triangle work beyond setup
    grows with the blocks its edges cross)."""

    triangles: float
    fragments: float
    edge: float


def coverage(view: MeshView) -> Coverage:
    """Coverage of `view`, computed once per distinct view (cached)."""
    return _coverage(*view.key())


@lru_cache(maxsize=4096)
def _coverage(triangles: int, frame: tuple[int, int], rect: tuple[int, int, int, int],
              first: int, count: int, eye: int | None) -> Coverage:
    if count <= 0:
        return Coverage(0.0, 0.0, 0.0)
    scale = 1.0
    if triangles > COVERAGE_SAMPLE_TRIANGLES:
        scale = triangles / COVERAGE_SAMPLE_TRIANGLES
        first, count = round(first / scale), max(1, round(count / scale))
        triangles = COVERAGE_SAMPLE_TRIANGLES
    pos = _projected(triangles, eye)[first:first + count]  # (n, 3, 2) pixels of a 1x1 frame
    w, h = frame
    px = pos * np.array([w, h], dtype=np.float64)
    x0, y0, rw, rh = rect
    lo, hi = px.min(axis=1), px.max(axis=1)
    reach = ((hi[:, 0] >= x0) & (lo[:, 0] <= x0 + rw) & (hi[:, 1] >= y0) & (lo[:, 1] <= y0 + rh))
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    centre = px.mean(axis=1)
    inside = ((centre[:, 0] >= x0) & (centre[:, 0] < x0 + rw)
              & (centre[:, 1] >= y0) & (centre[:, 1] < y0 + rh))
    return Coverage(triangles=float(reach.sum()) * scale,
                    fragments=float(area[inside].sum()),
                    edge=float(np.sqrt(area[reach]).sum()) * math.sqrt(scale))


@lru_cache(maxsize=16)
def _projected(triangles: int, eye: int | None) -> np.ndarray:
    """The torus's triangles in frame coordinates (0..1 across and down, Vulkan's viewport)."""
    verts = torus_mesh(triangles)[:, :3].astype(np.float64)
    clip = np.c_[verts, np.ones(len(verts))] @ mvp(eye).astype(np.float64).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return ((ndc + 1.0) / 2.0).reshape(-1, 3, 2)
