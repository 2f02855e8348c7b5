"""A unit sphere as a Wavefront OBJ with positions and normals, of exactly the requested number of
triangles, for vmgpu's basic (`-b`) mode.

Why a sphere: vmgpu places its camera from the mesh's bounds (at twice the largest z), so a
unit sphere fills the window's height at every resolution and the fragment work is the same
whatever the triangle count; its triangles are spread evenly, so sort-last's split of the index
list into equal parts gives each GPU an equal share. Why exact counts: the runs are compared by
triangle count, and a UV sphere alone only gives counts of the form 2 * slices * (stacks - 1);
the few missing triangles come from cutting band quads into four (two more triangles each, the
surface closed and free of T-junctions, whose cracks showed as black pixels) and, for an odd
count, one small triangle hidden at the sphere's centre (a closed triangle mesh always has an
even number of triangles).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mgpusim.vmgpu.failures import VmgpuMeasureError

MIN_TRIANGLES = 10_000
MAX_TRIANGLES = 5_000_000


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


@dataclass(frozen=True)
class MeshFile:
    """An OBJ written by `write_sphere`: where, and how many triangles and vertices it has."""

    path: Path
    triangles: int
    vertices: int


def layout(triangles: int) -> SphereLayout:
    """The stacks, slices and splits for exactly `triangles` triangles (slices about twice the
    stacks, so the sphere's quads are near square)."""
    if not MIN_TRIANGLES <= triangles <= MAX_TRIANGLES:
        raise VmgpuMeasureError(f"a sphere of {triangles} triangles was asked for; the meshes "
                                f"are made with {MIN_TRIANGLES}-{MAX_TRIANGLES} triangles")
    bands = max(2, round(math.sqrt(triangles / 4)))  # stacks - 1
    slices = triangles // (2 * bands)
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


def write_sphere(path: Path, triangles: int) -> MeshFile:
    """Write the sphere of exactly `triangles` triangles to `path` (through a temporary file, so
    a half-written mesh is never read as whole)."""
    shape = layout(triangles)
    positions, faces = sphere_arrays(shape)
    lengths = np.linalg.norm(positions, axis=1, keepdims=True)
    normals = np.where(lengths > 0.5, positions / np.maximum(lengths, 1e-12), [0.0, 0.0, 1.0])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w") as out:
        out.write(f"# unit sphere, {shape.triangles} triangles, {len(positions)} vertices\n")
        np.savetxt(out, positions, fmt="v %.6f %.6f %.6f")
        np.savetxt(out, normals, fmt="vn %.6f %.6f %.6f")
        one = faces + 1
        np.savetxt(out, np.repeat(one, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
    tmp.replace(path)
    return MeshFile(path=path, triangles=len(faces), vertices=len(positions))


def sphere_file(folder: Path, triangles: int) -> MeshFile:
    """The sphere of `triangles` triangles in `folder`, written if it is not there yet."""
    path = folder / f"sphere_{triangles}.obj"
    if path.is_file():
        return MeshFile(path=path, triangles=count_triangles(path), vertices=count_vertices(path))
    return write_sphere(path, triangles)


def count_triangles(path: Path) -> int:
    """The number of triangular faces in an OBJ file (a face of more corners is an error: vmgpu
    and this count would disagree on it)."""
    count = 0
    with path.open() as lines:
        for line in lines:
            if line.startswith("f "):
                if len(line.split()) != 4:
                    raise VmgpuMeasureError(f"{path}: a face that is not a triangle: {line.strip()}")
                count += 1
    return count


def count_vertices(path: Path) -> int:
    """The number of vertex positions (`v` lines) in an OBJ file."""
    with path.open() as lines:
        return sum(1 for line in lines if line.startswith("v "))
