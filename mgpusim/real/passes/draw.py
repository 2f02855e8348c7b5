"""Drawing helpers shared by every pass: push-constant quads, vertex draws, and the mesh and
the fixed camera (one definition for the runner's passes and the microbenchmarks alike)."""
from __future__ import annotations

import struct
from typing import Any, Sequence

import numpy as np

from mgpusim.model.geometry import mvp, torus_mesh  # noqa: F401  (torus_mesh: the passes' import)
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


def view_matrix(eye: int | None = None) -> bytes:
    """The fixed camera of :func:`mgpusim.model.geometry.mvp` as a column-major mat4 for GLSL."""
    return mvp(eye).T.astype(np.float32).tobytes()
