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
from mgpusim.model.sphere import sphere_arrays, sphere_layout

#: Half the distance between the eyes of the stereo camera (scene units; the torus is ~1.7 wide).
EYE_HALF_SEPARATION = 0.08
#: Our runner's camera: this far from the torus, which is tilted this much about x.
RUNNER_CAMERA_DISTANCE = 2.5
TORUS_TILT_DEGREES = 35
#: vmgpu's camera distance for the unit sphere: twice its largest z (src/Vmgpu.cpp).
BOUNDS_CAMERA_DISTANCE = 2.0
#: Above this many triangles, coverage is measured on a mesh of this many and scaled (the
#: covered area does not depend on the tessellation; a triangle's size goes as 1/sqrt(T)).
COVERAGE_SAMPLE_TRIANGLES = 200_000
#: The meshes a mesh pass may draw (its `shape`), each with the camera that views it:
#: `torus`, our runner's tilted torus and its fixed camera (:func:`mvp`); `sphere`, the unit
#: sphere the vmgpu tool writes (:mod:`.sphere`) as vmgpu views a mesh (:func:`bounds_mvp`).
SHAPES = ("torus", "sphere")
#: What a mesh pass's pipeline culls (its `cull`): `none` rasterizes every triangle (our
#: runner), `back` drops the triangles that face away from the camera after their setup and
#: before they are binned or rasterized (Vulkan's VK_CULL_MODE_BACK_BIT, bp's default).
CULLS = ("none", "back")
#: A pass's options that are names, not amounts: for each pass kind, option -> the names it
#: takes, the first its default. A mesh pass's mesh and what its pipeline culls (our runner
#: draws every combination).
PASS_OPTIONS: dict[str, dict[str, tuple[str, ...]]] = {"mesh": {"shape": SHAPES, "cull": CULLS}}
#: A measured mesh's options and their defaults (columns of its measure table; a table
#: without them measured the torus, unculled).
MESH_OPTIONS: dict[str, str] = {key: names[0] for key, names in PASS_OPTIONS["mesh"].items()}


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
    view[2, 3] = -RUNNER_CAMERA_DISTANCE
    view[0, 3] = _eye_shift(eye)
    tilt = np.eye(4, dtype=np.float32)
    ang = math.radians(TORUS_TILT_DEGREES)
    tilt[1:3, 1:3] = [[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]]
    return (proj @ view @ tilt).astype(np.float32)


def bounds_mvp(aspect: float, eye: int | None = None) -> np.ndarray:
    """How vmgpu views a mesh (src/Vmgpu.cpp): from twice the mesh's largest z on the z axis (2
    for the unit sphere), a 60-degree vertical field of view at the window's `aspect` (glm's
    perspective, near 0.1, far three times the mesh's size), y flipped in the vertex shader
    (shaders/basic.vert). Float64; `eye` as in :func:`mvp`."""
    f, near, far = 1.0 / math.tan(math.radians(30)), 0.1, 6.0
    proj = np.array([[f / aspect, 0, 0, 0], [0, -f, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                     [0, 0, -1, 0]])
    view = np.eye(4)
    view[2, 3] = -BOUNDS_CAMERA_DISTANCE
    view[0, 3] = _eye_shift(eye)
    return proj @ view


def _eye_shift(eye: int | None) -> float:
    """How far the view moves the world along x for camera `eye` (0 for mono)."""
    return 0.0 if eye is None else EYE_HALF_SEPARATION if eye == 0 else -EYE_HALF_SEPARATION


def _camera_at(shape: str, eye: int | None) -> np.ndarray:
    """Where `shape`'s camera `eye` sits in the mesh's own coordinates: back where its view
    moved the origin from (and, for the torus, its tilt undone)."""
    distance = BOUNDS_CAMERA_DISTANCE if shape == "sphere" else RUNNER_CAMERA_DISTANCE
    at = np.array([-_eye_shift(eye), 0.0, distance])
    if shape == "sphere":
        return at
    ang = math.radians(TORUS_TILT_DEGREES)
    untilt = np.array([[1, 0, 0], [0, math.cos(ang), math.sin(ang)], [0, -math.sin(ang), math.cos(ang)]])
    return untilt @ at


@dataclass(frozen=True)
class MeshView:
    """What one mesh pass draws: triangles [first, first + count) of a mesh of `triangles`
    (`shape`, one of :data:`SHAPES`), seen by camera `eye`, into pixels `rect` = (x, y, w, h)
    of a `frame` (w, h), `cull` one of :data:`CULLS`."""

    triangles: int
    frame: tuple[int, int]
    rect: tuple[int, int, int, int] | None = None
    first: int = 0
    count: int | None = None
    eye: int | None = None
    shape: str = "torus"
    cull: str = "none"

    def key(self) -> tuple:
        rect = self.rect or (0, 0, *self.frame)
        count = self.triangles - self.first if self.count is None else self.count
        return (self.triangles, self.frame, rect, self.first, count, self.eye, self.shape, self.cull)


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

    def mesh_view(self, triangles: int, shape: str = "torus", cull: str = "none") -> MeshView:
        k, n = self.share
        first = triangles * k // n
        return MeshView(triangles, self.frame, self.rect, first,
                        triangles * (k + self.span) // n - first, self.eye, shape, cull)


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
              first: int, count: int, eye: int | None, shape: str = "torus",
              cull: str = "none") -> Coverage:
    if count <= 0:
        return Coverage(0.0, 0.0, 0.0)
    scale = 1.0
    if triangles > COVERAGE_SAMPLE_TRIANGLES:
        scale = triangles / COVERAGE_SAMPLE_TRIANGLES
        first, count = round(first / scale), max(1, round(count / scale))
        triangles = COVERAGE_SAMPLE_TRIANGLES
    w, h = frame
    # the torus's camera ignores the frame's shape (our runner's); vmgpu's has its aspect
    aspect = None if shape == "torus" else w / h
    pos, front = _projected(triangles, eye, shape, aspect)
    pos = pos[first:first + count]  # (n, 3, 2) pixels of a 1x1 frame
    if cull == "back":
        pos = pos[front[first:first + count]]
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
def _projected(triangles: int, eye: int | None, shape: str = "torus",
               aspect: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's triangles in frame coordinates (0..1 across and down, Vulkan's viewport), and
    which of them face the camera (their outward normal towards it)."""
    if shape == "sphere":
        positions, faces = sphere_arrays(sphere_layout(triangles))
        corners = positions[faces]  # (T, 3, 3)
        verts = corners.reshape(-1, 3)
        outward = corners.mean(axis=1)  # a unit sphere's normal is its position
        matrix = bounds_mvp(aspect or 1.0, eye)
    else:
        mesh = torus_mesh(triangles).astype(np.float64)
        verts = mesh[:, :3]
        outward = mesh[:, 3:].reshape(-1, 3, 3).mean(axis=1)
        matrix = mvp(eye).astype(np.float64)
    clip = np.c_[verts, np.ones(len(verts))] @ matrix.T
    ndc = clip[:, :2] / clip[:, 3:4]
    centres = verts.reshape(-1, 3, 3).mean(axis=1)
    front = np.einsum("ij,ij->i", outward, _camera_at(shape, eye) - centres) > 0
    return ((ndc + 1.0) / 2.0).reshape(-1, 3, 2), front
