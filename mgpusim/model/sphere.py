"""The unit sphere vmgpu draws in these runs (the `sphere` mesh shape), exactly as the vmgpu
tool writes it: a UV sphere of exactly the requested number of triangles, poles on the y axis.

Why in the model: the cost model projects the mesh a renderer draws to count what each view
rasterizes (:mod:`.geometry`), so the sphere the runs drew and the sphere the model projects
must be one mesh, triangle for triangle and in the same order (sort-last splits the index
list in order). Why exact counts: the runs are compared by triangle count, and a UV sphere
alone only gives counts of the form 2 * slices * (stacks - 1); the few missing triangles come
from cutting band quads into four (two more triangles each, the surface closed and free of
T-junctions) and, for an odd count, one small triangle hidden at the sphere's centre (a closed
triangle mesh always has an even number of triangles).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SphereLayout:
    """How a sphere of `triangles` triangles is cut: `stacks` latitude bands, `slices` longitude
    sectors, and `extra` triangles beyond the UV sphere's 2 * slices * (stacks - 1) to reach the
    exact count (extra // 2 quads cut in four, extra % 2 hidden centre triangles)."""

    stacks: int
    slices: int
    extra: int

    @property
    def triangles(self) -> int:
        return 2 * self.slices * (self.stacks - 1) + self.extra


def sphere_layout(triangles: int) -> SphereLayout:
    """The stacks, slices and splits for exactly `triangles` (>= 8) triangles (slices about
    twice the stacks, so the sphere's quads are near square)."""
    bands = max(2, round(math.sqrt(triangles / 4)))  # stacks - 1
    slices = max(3, triangles // (2 * bands))
    return SphereLayout(stacks=bands + 1, slices=slices, extra=triangles - 2 * bands * slices)


def sphere_arrays(shape: SphereLayout) -> tuple[np.ndarray, np.ndarray]:
    """The sphere's vertex positions (V x 3) and triangles (T x 3, 0-based, counter-clockwise
    seen from outside)."""
    rings = _ring_positions(shape)
    north = np.array([[0.0, 1.0, 0.0]])
    south = np.array([[0.0, -1.0, 0.0]])
    positions = np.vstack([north, rings, south])
    faces = _faces(shape, south_index=len(positions) - 1)
    return _split(positions, faces, shape)


def sphere_normals(positions: np.ndarray) -> np.ndarray:
    """Each vertex's unit normal: its direction from the centre (a unit sphere's), +z for the
    hidden centre triangle's vertices at or near the centre (which have none)."""
    lengths = np.linalg.norm(positions, axis=1, keepdims=True)
    return np.where(lengths > 0.5, positions / np.maximum(lengths, 1e-12), [0.0, 0.0, 1.0])


def _ring_positions(shape: SphereLayout) -> np.ndarray:
    """The vertices of the stacks - 1 rings between the poles, ring by ring."""
    theta = np.arange(1, shape.stacks) * math.pi / shape.stacks
    phi = np.arange(shape.slices) * 2 * math.pi / shape.slices
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)


def _faces(shape: SphereLayout, south_index: int) -> np.ndarray:
    """The two pole fans and the bands' quads (two triangles each), outward facing."""
    n, bands = shape.slices, shape.stacks - 1
    j = np.arange(n)
    jn = (j + 1) % n

    def ring(i: int) -> int:
        return 1 + i * n

    north = np.stack([np.zeros(n, dtype=np.int64), ring(0) + jn, ring(0) + j], axis=1)
    south = np.stack([ring(bands - 1) + j, ring(bands - 1) + jn, np.full(n, south_index)], axis=1)
    i = np.arange(bands - 1)[:, None]
    v00, v01 = ring(0) + i * n + j, ring(0) + i * n + jn
    v10, v11 = v00 + n, v01 + n
    first = np.stack([v00, v01, v10], axis=-1)
    second = np.stack([v01, v11, v10], axis=-1)
    quads = np.stack([first, second], axis=2).reshape(-1, 3)  # band by band, quad by quad
    return np.vstack([north, quads, south]).astype(np.int64)


def _split(positions: np.ndarray, faces: np.ndarray, shape: SphereLayout,
           ) -> tuple[np.ndarray, np.ndarray]:
    """Cut `shape.extra // 2` band quads, spread over the sphere, into four triangles around the
    midpoint of their diagonal, and for an odd `extra` add one small triangle at the centre."""
    quads = (shape.stacks - 2) * shape.slices
    pairs = shape.extra // 2
    if pairs:
        chosen = np.linspace(0, quads - 1, pairs).astype(np.int64)
        first = shape.slices + 2 * chosen  # each chosen quad's two rows: (v00 v01 v10), (v01 v11 v10)
        v00, v01, v10 = faces[first, 0], faces[first, 1], faces[first, 2]
        v11 = faces[first + 1, 1]
        mid = len(positions) + np.arange(pairs)
        positions = np.vstack([positions, (positions[v01] + positions[v10]) / 2])
        faces = faces.copy()
        faces[first] = np.stack([v00, v01, mid], axis=1)
        faces[first + 1] = np.stack([v01, v11, mid], axis=1)
        faces = np.vstack([faces, np.stack([v11, v10, mid], axis=1),
                           np.stack([v10, v00, mid], axis=1)])
    if shape.extra % 2:
        n = len(positions)
        positions = np.vstack([positions, [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]]])
        faces = np.vstack([faces, [[n, n + 1, n + 2]]])
    return positions, faces
