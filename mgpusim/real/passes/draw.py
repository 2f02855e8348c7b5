"""Drawing helpers shared by every pass: push-constant quads, vertex draws, and the mesh and
the fixed camera (one definition for the runner's passes and the microbenchmarks alike)."""
from __future__ import annotations

import struct
from typing import Any, Sequence

import numpy as np

from mgpusim.model.geometry import bounds_mvp, mvp, torus_mesh  # noqa: F401  (torus_mesh: the passes' import)
from mgpusim.model.sphere import sphere_arrays, sphere_layout, sphere_normals
from mgpusim.real.vulkan.vk_errors import vk


def stages() -> int:
    v = vk()
    return v.VK_SHADER_STAGE_VERTEX_BIT | v.VK_SHADER_STAGE_FRAGMENT_BIT


def quad_pc(rect: Sequence[float], uv: Sequence[float], extra: Sequence[float] = (0, 0, 0, 0)) -> bytes:
    return struct.pack("12f", *rect, *uv, *extra)


def draw_vertices(cmd: Any, pipeline: Any, push: bytes, vertices: Any, count: int, first: int = 0) -> None:
    """Inside a begun render pass: bind `pipeline`, push constants, one vertex buffer, draw."""
    v = vk()
    pipeline.bind(cmd)
    pipeline.push(cmd, stages(), push)
    buffers, offsets = [vertices.handle], [0]  # bound to names: they must outlive the call
    v.vkCmdBindVertexBuffers(cmd, 0, 1, buffers, offsets)
    v.vkCmdDraw(cmd, count, 1, first, 0)


def draw_indexed(cmd: Any, pipeline: Any, push: bytes, vertex_buffers: Sequence[Any],
                 indices: Any, count: int) -> None:
    """Inside a begun render pass: bind `pipeline`, push constants, one vertex buffer per
    attribute and a 32-bit index buffer, draw `count` indices (vmgpu's draw: bpScene's
    MeshResources binds the same)."""
    v = vk()
    pipeline.bind(cmd)
    pipeline.push(cmd, stages(), push)
    buffers, offsets = [b.handle for b in vertex_buffers], [0] * len(vertex_buffers)
    v.vkCmdBindVertexBuffers(cmd, 0, len(buffers), buffers, offsets)
    v.vkCmdBindIndexBuffer(cmd, indices.handle, 0, v.VK_INDEX_TYPE_UINT32)
    v.vkCmdDrawIndexed(cmd, count, 1, 0, 0, 0)


def sphere_geometry(triangles: int, first: int, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sphere of `triangles` triangles as vmgpu's buffers hold it: positions and normals
    (float32, one vertex per distinct position, as bpScene's OBJ loader keeps them) and the
    32-bit indices of triangles [first, first + count)."""
    positions, faces = sphere_arrays(sphere_layout(triangles))
    return (positions.astype(np.float32), sphere_normals(positions).astype(np.float32),
            np.ascontiguousarray(faces[first:first + count], dtype=np.uint32).reshape(-1))


def sphere_matrices(frame: tuple[int, int], eye: int | None = None) -> bytes:
    """vmgpu's camera on the sphere (:func:`mgpusim.model.geometry.bounds_mvp` at the frame's
    aspect) and its normal matrix (the identity: the mesh is not turned), column-major mat4s."""
    matrix = bounds_mvp(frame[0] / frame[1], eye).T.astype(np.float32)
    return matrix.tobytes() + np.eye(4, dtype=np.float32).tobytes()


def view_matrix(eye: int | None = None) -> bytes:
    """The fixed camera of :func:`mgpusim.model.geometry.mvp` as a column-major mat4 for GLSL."""
    return mvp(eye).T.astype(np.float32).tobytes()
