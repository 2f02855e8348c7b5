"""The sphere OBJs for vmgpu: exactly the asked-for triangle count, closed, facing out."""
from __future__ import annotations

import numpy as np
import pytest

from mgpusim.vmgpu import meshes
from mgpusim.vmgpu.failures import VmgpuMeasureError


@pytest.mark.parametrize("triangles", [10_000, 10_001, 99_999, 100_000, 1_000_000, 1_234_567,
                                       4_999_999, 5_000_000])
def test_the_layout_gives_exactly_the_count(triangles):
    shape = meshes.layout(triangles)
    assert shape.triangles == triangles
    assert 0 <= shape.extra < 2 * (shape.stacks - 1)
    assert shape.slices >= shape.stacks  # near-square quads: about twice as many slices


@pytest.mark.parametrize("triangles", [9_999, 5_000_001, 0, -5])
def test_a_count_out_of_range_is_one_clear_error(triangles):
    with pytest.raises(VmgpuMeasureError, match=f"{triangles} triangles"):
        meshes.layout(triangles)


@pytest.mark.parametrize("triangles", [10_000, 10_001, 12_346, 12_347])
def test_the_arrays_are_a_closed_outward_sphere(triangles):
    positions, faces = meshes.sphere_arrays(meshes.layout(triangles))
    assert len(faces) == triangles
    assert faces.min() == 0 and faces.max() == len(positions) - 1
    a, b, c = (positions[faces[:, k]] for k in range(3))
    centre = (a + b + c) / 3
    on_sphere = np.linalg.norm(centre, axis=1) > 0.5
    assert (~on_sphere).sum() == triangles % 2  # the one hidden centre triangle of an odd count
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), centre)
    assert (outward[on_sphere] > 0).all()
    shell = faces[on_sphere]
    edges = np.vstack([shell[:, [0, 1]], shell[:, [1, 2]], shell[:, [2, 0]]])
    assert len(np.unique(edges, axis=0)) == len(edges)  # each directed edge once
    _, uses = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
    assert (uses == 2).all()  # closed: no crack, no T-junction


@pytest.mark.parametrize("triangles", [10_000, 10_001, 23_457])
def test_the_written_obj_has_exactly_the_count(tmp_path, triangles):
    mesh = meshes.write_sphere(tmp_path / "s.obj", triangles)
    assert mesh.triangles == triangles
    assert meshes.count_triangles(mesh.path) == triangles
    assert meshes.count_vertices(mesh.path) == mesh.vertices
    lines = mesh.path.read_text().splitlines()
    normals = np.array([[float(v) for v in line.split()[1:]] for line in lines if line.startswith("vn ")])
    assert len(normals) == mesh.vertices
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    face = next(line for line in lines if line.startswith("f "))
    assert all("//" in corner for corner in face.split()[1:])  # position//normal, as vmgpu's -b reads
    assert not list(tmp_path.glob("*.tmp"))


def test_a_mesh_already_written_is_reused(tmp_path):
    first = meshes.sphere_file(tmp_path, 10_000)
    stamp = first.path.stat().st_mtime_ns
    again = meshes.sphere_file(tmp_path, 10_000)
    assert again == first and again.path.stat().st_mtime_ns == stamp


def test_a_face_that_is_not_a_triangle_is_refused(tmp_path):
    obj = tmp_path / "quad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    with pytest.raises(VmgpuMeasureError, match="not a triangle"):
        meshes.count_triangles(obj)
