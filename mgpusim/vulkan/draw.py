"""Drawing helpers shared by every pass: push-constant quads, vertex draws, the torus mesh and
the fixed camera (one definition for the runner's passes and the microbenchmarks alike)."""
from __future__ import annotations

import math
import struct
from typing import Any, Sequence

import numpy as np

from ..errors import InputError
from .errors import vk


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


#: Half the distance between the eyes of the stereo camera (scene units; the torus is ~1.7 wide).
EYE_HALF_SEPARATION = 0.08


def view_matrix(eye: int | None = None) -> bytes:
    """A fixed perspective camera looking at the origin (column-major mat4 for GLSL); `eye`
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
    return (proj @ view @ tilt).T.astype(np.float32).tobytes()
