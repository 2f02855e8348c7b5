"""Particle update + billboard build (docs/sources.md: particles on a secondary GPU) as a compute
pass, and its numpy reference.

Why a numpy reference here: the tests compare the shader with it, and the runner can use it to
check offloaded particle results. Layout per particle (std430): pos, dir (w = velocity),
spawn (w = billboard half-size), life (x = alive, y = maxLife) = 64 B of state; the pass writes
2 float4 to the calc buffer and 12 float4 (6 vertices x (pos, uv)) = 192 B to the vertex buffer.
"""
from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.model.particle_layout import CALC_BYTES, STATE_BYTES, UPDATE_DT, VERTEX_BYTES
from mgpusim.real.vulkan.copies import upload
from mgpusim.real.vulkan.pipelines import compute_pipeline
from mgpusim.real.vulkan.vk_errors import vk

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu

RIGHT = (1.0, 0.0, 0.0, 0.0)
UP = (0.0, 1.0, 0.0, 0.0)
_CORNERS = np.array([(-1, -1), (1, -1), (-1, 1), (1, -1), (1, 1), (-1, 1)], dtype=np.float32)


def initial_state(particles: int, seed: int = 0) -> np.ndarray:
    """float32 (P, 4, 4): pos, dir+vel, spawn+size, life; a reproducible fountain."""
    rng = np.random.default_rng(seed)
    s = np.zeros((particles, 4, 4), dtype=np.float32)
    s[:, 3, 1] = rng.uniform(0.5, 2.0, particles)            # maxLife
    s[:, 3, 0] = rng.uniform(0.0, 1.0, particles) * s[:, 3, 1]  # alive
    s[:, 2, :3] = rng.uniform(-0.3, 0.3, (particles, 3))     # spawn position
    s[:, 2, 3] = 0.02                                         # half-size
    d = rng.normal(size=(particles, 3)) + (0, 2, 0)
    s[:, 1, :3] = d / np.linalg.norm(d, axis=1, keepdims=True)
    s[:, 1, 3] = rng.uniform(0.2, 0.6, particles)             # velocity
    s[:, 0, :3] = s[:, 2, :3] + s[:, 1, :3] * s[:, 1, 3:4] * s[:, 3, 0:1]
    s[:, 0, 3] = 1.0
    return s


def reference_update(state: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """numpy version of particles.comp: (new state, calc (P,2,4), vertices (P,12,4))."""
    s = state.astype(np.float32).copy()
    dt32 = np.float32(dt)
    if dt32 > 0:
        s[:, 3, 0] += dt32
        dead = s[:, 3, 0] > s[:, 3, 1]
        moved = s[:, 0, :3] + s[:, 1, :3] * s[:, 1, 3:4] * dt32
        s[:, 0, :3] = np.where(dead[:, None], s[:, 2, :3], moved)
        s[:, 0, 3] = np.where(dead, s[:, 2, 3], s[:, 0, 3])
        s[:, 3, 0] = np.where(dead, 0.0, s[:, 3, 0])
    calc = np.zeros((len(s), 2, 4), dtype=np.float32)
    calc[:, 0] = s[:, 0]
    calc[:, 1, :2] = s[:, 3, :2]
    right, up = np.array(RIGHT[:3], np.float32), np.array(UP[:3], np.float32)
    offs = (_CORNERS[:, :1] * right + _CORNERS[:, 1:] * up)[None] * s[:, 2, 3][:, None, None]
    verts = np.zeros((len(s), 6, 2, 4), dtype=np.float32)
    verts[:, :, 0, :3] = s[:, None, 0, :3] + offs
    verts[:, :, 0, 3] = 1.0
    verts[:, :, 1, :2] = _CORNERS * 0.5 + 0.5
    return s, calc, verts.reshape(len(s), 12, 4)


class ParticleUpdate:
    """The compute pass: update P particles by `dt` and build their billboards.

    The runner gives it the vertex buffers it writes (`vertices`, one per buffered copy: the
    offloaded vertex buffer crosses GPUs from there) and the state buffer it keeps; the
    microbenchmark lets it make its own. `record(cmd, slot, dt)` writes copy `slot`, with a
    time step other than `dt` where the caller asks (skipped updates' time accumulates)."""

    queue = "compute"

    def __init__(self, gpu: "Gpu", particles: int, *, dt: float = UPDATE_DT, seed: int = 0,
                 state: np.ndarray | None = None, vertices: Sequence[Any] | None = None,
                 state_buffer: Any = None):
        if particles <= 0:
            raise InputError(f"must be positive, got {particles}", field="particles")
        self.gpu, self.particles, self.dt = gpu, particles, dt
        self._mine: list[Any] = []
        self.state = state_buffer or self._make(particles * STATE_BYTES)
        self.calc = self._make(particles * CALC_BYTES)
        self.outputs = list(vertices) if vertices else [self._make(particles * VERTEX_BYTES)]
        self.vertices = self.outputs[0]
        upload(gpu, self.state, initial_state(particles, seed) if state is None else state)
        self.pipeline = compute_pipeline(gpu, "particles.comp", buffers=3, push_size=40,
                                         max_sets=len(self.outputs))
        self.sets = [self.pipeline.descriptor_set([self.state, self.calc, out])
                     for out in self.outputs]
        self.bytes = particles * (STATE_BYTES + CALC_BYTES + VERTEX_BYTES)

    def _make(self, size: int) -> Any:
        buf = self.gpu.buffer(size, host_visible=False)
        self._mine.append(buf)
        return buf

    def push_constants(self, dt: float) -> bytes:
        return struct.pack("8ffI", *RIGHT, *UP, dt, self.particles)

    def record(self, cmd: Any, slot: int = 0, dt: float | None = None) -> None:
        v = vk()
        self.pipeline.bind(cmd, self.sets[slot])
        self.pipeline.push(cmd, v.VK_SHADER_STAGE_COMPUTE_BIT,
                           self.push_constants(self.dt if dt is None else dt))
        v.vkCmdDispatch(cmd, -(-self.particles // 64), 1, 1)

    def destroy(self) -> None:
        self.pipeline.destroy()
        for buf in self._mine:
            buf.destroy()
        self._mine.clear()
