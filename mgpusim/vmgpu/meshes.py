"""A unit sphere as a Wavefront OBJ with positions and normals, of exactly the requested number of
triangles, for vmgpu's basic (`-b`) mode.

Why a sphere: vmgpu places its camera from the mesh's bounds (at twice the largest z), so a
unit sphere fills the window's height at every resolution and the fragment work is the same
whatever the triangle count; its triangles are spread evenly, so sort-last's split of the index
list into equal parts gives each GPU an equal share. The sphere itself (its exact triangle
count, its order) is the model's `sphere` mesh shape, :mod:`mgpusim.model.sphere`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mgpusim.model.sphere import SphereLayout, sphere_arrays, sphere_layout, sphere_normals
from mgpusim.vmgpu.failures import VmgpuMeasureError

MIN_TRIANGLES = 10_000
MAX_TRIANGLES = 5_000_000


@dataclass(frozen=True)
class MeshFile:
    """An OBJ written by `write_sphere`: where, and how many triangles and vertices it has."""

    path: Path
    triangles: int
    vertices: int


def layout(triangles: int) -> SphereLayout:
    """The stacks, slices and splits for exactly `triangles` triangles, within the sizes the
    runs use."""
    if not MIN_TRIANGLES <= triangles <= MAX_TRIANGLES:
        raise VmgpuMeasureError(f"a sphere of {triangles} triangles was asked for; the meshes "
                                f"are made with {MIN_TRIANGLES}-{MAX_TRIANGLES} triangles")
    return sphere_layout(triangles)


def write_sphere(path: Path, triangles: int) -> MeshFile:
    """Write the sphere of exactly `triangles` triangles to `path` (through a temporary file, so
    a half-written mesh is never read as whole)."""
    shape = layout(triangles)
    positions, faces = sphere_arrays(shape)
    normals = sphere_normals(positions)
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
