"""The pass library: real Vulkan workloads with their knobs (issue 3, DOMAIN.md 3.1-3.4).

Every pass is built once (resources, pipelines: the slow part) and then recorded any number of
times with `record(cmd)` inside `Gpu.submit`. `queue` is the family it runs on by default and
`bytes` the bytes it writes (the measure table's `bytes` column).
"""
from __future__ import annotations

import math
import struct
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..errors import InputError
from .copies import upload
from .memory import DEPTH_FORMAT, Buffer, Image
from .particles import ParticleUpdate
from .pipelines import RenderTarget, graphics_pipeline
from .errors import vk

if TYPE_CHECKING:
    from .device import Gpu



def _stages() -> int:
    v = vk()
    return v.VK_SHADER_STAGE_VERTEX_BIT | v.VK_SHADER_STAGE_FRAGMENT_BIT


def _quad_pc(rect: Sequence[float], uv: Sequence[float], extra: Sequence[float] = (0, 0, 0, 0)) -> bytes:
    return struct.pack("12f", *rect, *uv, *extra)


def _positive(**values: int) -> None:
    for name, value in values.items():
        if value <= 0:
            raise InputError(f"must be positive, got {value}", field=name)


def tile_rows(height: int, n: int) -> list[tuple[int, int]]:
    """Sort-first split: n horizontal tiles (y0, rows) of equal height, the last takes the rest."""
    base = height // n
    if base == 0:
        raise InputError(f"cannot split {height} rows into {n} tiles", field="inputs")
    return [(i * base, base if i < n - 1 else height - base * (n - 1)) for i in range(n)]


class _GraphicsPass:
    queue = "graphics"

    def __init__(self, gpu: "Gpu"):
        self.gpu = gpu
        self._owned: list[Any] = []

    def destroy(self) -> None:
        for obj in reversed(self._owned):
            obj.destroy()


class FragmentLoop(_GraphicsPass):
    """Full-screen rectangle whose fragment shader loops `iterations` times (the thesis benchmark).

    The target is the viewport or tile (`width` x `height`); `frame` and `offset` place it in the
    full frame so the tile's uv (and so its pixels) match the full-frame render.
    """

    def __init__(self, gpu: "Gpu", width: int, height: int, iterations: int, *,
                 frame: tuple[int, int] | None = None, offset: tuple[int, int] = (0, 0)):
        super().__init__(gpu)
        _positive(width=width, height=height)
        if iterations < 0:
            raise InputError(f"must be >= 0, got {iterations}", field="iterations")
        self.width, self.height, self.iterations = width, height, iterations
        fw, fh = frame or (width, height)
        ox, oy = offset
        self.target = RenderTarget(gpu, width, height, depth=False)
        self.pipeline = graphics_pipeline(gpu, self.target, "quad.vert", "loop.frag")
        self._owned += [self.target, self.pipeline]
        self._pc = _quad_pc((-1, -1, 1, 1), (ox / fw, oy / fh, (ox + width) / fw,
                                               (oy + height) / fh), (iterations, 0, 0, 0))
        self.bytes = width * height * 4

    def record(self, cmd: Any) -> None:
        v = vk()
        self.target.begin(cmd)
        self.pipeline.bind(cmd)
        self.pipeline.push(cmd, _stages(), self._pc)
        v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


def draw_vertices(cmd: Any, pipeline: Any, push: bytes, vertices: Any, count: int, first: int = 0) -> None:
    """Inside a begun render pass: bind `pipeline`, push constants, one vertex buffer, draw."""
    v = vk()
    pipeline.bind(cmd)
    pipeline.push(cmd, _stages(), push)
    buffers, offsets = [vertices.handle], [0]  # bound to names: they must outlive the call
    v.vkCmdBindVertexBuffers(cmd, 0, 1, buffers, offsets)
    v.vkCmdDraw(cmd, count, 1, first, 0)


def torus_mesh(triangles: int, radius: float = 0.6, tube: float = 0.25) -> np.ndarray:
    """A tessellated torus of exactly `triangles` triangles: float32 (3*T, 6) = position, normal."""
    _positive(triangles=triangles)
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


def _view_matrix() -> bytes:
    """A fixed perspective camera looking at the origin (column-major mat4 for GLSL)."""
    f, near, far = 1.0 / math.tan(math.radians(30)), 0.5, 10.0
    proj = np.array([[f, 0, 0, 0], [0, f, 0, 0], [0, 0, far / (near - far), near * far / (near - far)],
                     [0, 0, -1, 0]], dtype=np.float32)
    view = np.eye(4, dtype=np.float32)
    view[2, 3] = -2.5
    tilt = np.eye(4, dtype=np.float32)
    ang = math.radians(35)
    tilt[1:3, 1:3] = [[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]]
    return (proj @ view @ tilt).T.astype(np.float32).tobytes()


class Mesh(_GraphicsPass):
    """T triangles of a generated torus into colour RGBA8 + depth D16 (`first`..: a share)."""

    def __init__(self, gpu: "Gpu", width: int, height: int, triangles: int, *,
                 first: int = 0, count: int | None = None):
        super().__init__(gpu)
        _positive(width=width, height=height, triangles=triangles)
        self.width, self.height, self.triangles = width, height, triangles
        self.first, self.count = first, (triangles - first if count is None else count)
        verts = torus_mesh(triangles)
        self.vertices = gpu.buffer(verts.nbytes, host_visible=False)
        upload(gpu, self.vertices, verts)
        self.target = RenderTarget(gpu, width, height, depth=True)
        self.pipeline = graphics_pipeline(
            gpu, self.target, "mesh.vert", "mesh.frag", push_size=64, stride=24,
            vertex_attributes=[(0, "R32G32B32_SFLOAT", 0), (1, "R32G32B32_SFLOAT", 12)],
            depth_test=True)
        self._owned += [self.vertices, self.target, self.pipeline]
        self._mvp = _view_matrix()
        self.bytes = width * height * 6

    def record(self, cmd: Any) -> None:
        self.target.begin(cmd)
        draw_vertices(cmd, self.pipeline, self._mvp, self.vertices, 3 * self.count, 3 * self.first)
        vk().vkCmdEndRenderPass(cmd)


class CompositeSortFirst(_GraphicsPass):
    """One rectangle per contribution, sampling its colour tile into its rows of the frame.

    `inputs[i]` is a (width x rows_i) RGBA8 image; give your own (the runner's uploaded
    contributions) or let the pass create them.
    """

    def __init__(self, gpu: "Gpu", width: int, height: int, inputs: int, *,
                 textures: Sequence[Image] | None = None):
        super().__init__(gpu)
        _positive(width=width, height=height, inputs=inputs)
        self.width, self.height = width, height
        self.tiles = tile_rows(height, inputs)
        if textures is None:
            textures = [gpu.image(width, rows) for _, rows in self.tiles]
            self._owned += list(textures)
        self.inputs = list(textures)
        self.target = RenderTarget(gpu, width, height, depth=False)
        self.pipeline = graphics_pipeline(gpu, self.target, "quad.vert", "sample.frag", samplers=1,
                                          max_sets=inputs)
        self._owned += [self.target, self.pipeline]
        self.sets = [self.pipeline.descriptor_set([img]) for img in self.inputs]
        self._pcs = [_quad_pc((-1, -1 + 2 * y0 / height, 1, -1 + 2 * (y0 + rows) / height),
                              (0, 0, 1, 1)) for y0, rows in self.tiles]
        self.bytes = width * height * 4

    def record(self, cmd: Any) -> None:
        v = vk()
        self.target.begin(cmd)
        for dset, pc in zip(self.sets, self._pcs):
            self.pipeline.bind(cmd, dset)
            self.pipeline.push(cmd, _stages(), pc)
            v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


class CompositeSortLast(_GraphicsPass):
    """A full-screen quad per contribution writing its colour and depth; depth test keeps nearest."""

    def __init__(self, gpu: "Gpu", width: int, height: int, inputs: int, *,
                 textures: Sequence[tuple[Image, Image]] | None = None):
        super().__init__(gpu)
        _positive(width=width, height=height, inputs=inputs)
        self.width, self.height = width, height
        if textures is None:
            textures = [(gpu.image(width, height), gpu.image(width, height, DEPTH_FORMAT))
                        for _ in range(inputs)]
            self._owned += [img for pair in textures for img in pair]
        self.inputs = list(textures)
        self.target = RenderTarget(gpu, width, height, depth=True)
        self.pipeline = graphics_pipeline(gpu, self.target, "quad.vert", "sample_depth.frag",
                                          samplers=2, depth_test=True, max_sets=inputs)
        self._owned += [self.target, self.pipeline]
        self.sets = [self.pipeline.descriptor_set([c, d]) for c, d in self.inputs]
        self._pc = _quad_pc((-1, -1, 1, 1), (0, 0, 1, 1))
        self.bytes = width * height * 6

    def record(self, cmd: Any) -> None:
        v = vk()
        self.target.begin(cmd)
        for dset in self.sets:
            self.pipeline.bind(cmd, dset)
            self.pipeline.push(cmd, _stages(), self._pc)
            v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


class ParticleRender(_GraphicsPass):
    """Draw P billboards (6 vertices each, built by ParticleUpdate) additively into RGBA8."""

    def __init__(self, gpu: "Gpu", width: int, height: int, particles: int, *,
                 vertices: Buffer | None = None, seed: int = 0):
        super().__init__(gpu)
        _positive(width=width, height=height, particles=particles)
        self.width, self.height, self.particles = width, height, particles
        if vertices is None:
            update = ParticleUpdate(gpu, particles, seed=seed)
            gpu.run("compute", update.record)
            self._owned.append(update)
            vertices = update.vertices
        self.vertices = vertices
        self.target = RenderTarget(gpu, width, height, depth=False)
        self.pipeline = graphics_pipeline(
            gpu, self.target, "particle.vert", "particle.frag", push_size=64, stride=32,
            vertex_attributes=[(0, "R32G32B32A32_SFLOAT", 0), (1, "R32G32B32A32_SFLOAT", 16)],
            blend_add=True)
        self._owned += [self.target, self.pipeline]
        self._mvp = _view_matrix()
        self.bytes = width * height * 4

    def record(self, cmd: Any) -> None:
        self.target.begin(cmd)
        draw_vertices(cmd, self.pipeline, self._mvp, self.vertices, 6 * self.particles)
        vk().vkCmdEndRenderPass(cmd)
