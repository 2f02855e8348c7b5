"""The pass library as microbenchmarks: each pass on targets and inputs of its own.

Why thin wrappers: the work itself is implemented once, in :mod:`.recorders` (what the runner
executes inside a schedule: the fragment loop on a tile of the frame, a share of the mesh, the
composite drawing into the frame it loads, present as an image copy). Each class here builds
the images that pass needs and records exactly that work, so `mgpusim measure` times what the
runner runs and the calibration needs no second form of any pass.

Every pass is built once (resources, pipelines: the slow part) and then recorded any number of
times with `record(cmd)` inside `Gpu.submit`. `queue` is the family it runs on by default and
`bytes` the bytes it writes (the measure table's `bytes` column).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.model.geometry import even_split
from mgpusim.real.passes.draw import torus_mesh  # noqa: F401  (re-exported: the tests build meshes with it)
from mgpusim.real.passes.particle_update import ParticleUpdate
from mgpusim.real.passes.recorders import (
    CompositeInto,
    Filter,
    FragmentLoopTile,
    MeshShare,
    ParticleDraw,
    check_mesh_options,
    copy_image,
)
from mgpusim.real.vulkan.buffers import DEPTH_FORMAT, Buffer, Image
from mgpusim.real.vulkan.copies import clear_images, upload
from mgpusim.real.vulkan.pipelines import RenderTarget

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu



def _positive(**values: int) -> None:
    for name, value in values.items():
        if value <= 0:
            raise InputError(f"must be positive, got {value}", field=name)


def tile_rows(height: int, n: int) -> list[tuple[int, int]]:
    """Sort-first split: n horizontal tiles (y0, rows) of equal height, the last takes the rest."""
    if height // n == 0:
        raise InputError(f"cannot split {height} rows into {n} tiles", field="inputs")
    rows = even_split(height, n)
    return [(sum(rows[:i]), r) for i, r in enumerate(rows)]


class _GraphicsPass:
    """A pass that owns what it draws with; `destroy` frees it in reverse order."""

    queue = "graphics"
    work: Any  # the runner's pass that `record` records: each subclass makes one

    def __init__(self, gpu: "Gpu"):
        self.gpu = gpu
        self._owned: list[Any] = []

    def destroy(self) -> None:
        for obj in reversed(self._owned):
            obj.destroy()
        self._owned.clear()

    def record(self, cmd: Any) -> None:
        """The runner's own pass (`self.work`), on this pass's images (slot 0)."""
        self.work.record(cmd, 0)


class FragmentLoop(_GraphicsPass):
    """Full-screen rectangle whose fragment shader loops `iterations` times (the sort-first
    benchmark), as the runner's tile pass. The target is the viewport or tile (`width` x
    `height`); `frame` and `offset` place it in the full frame, so the tile's pixels match the
    full-frame render."""

    def __init__(self, gpu: "Gpu", width: int, height: int, iterations: int, *,
                 frame: tuple[int, int] | None = None, offset: tuple[int, int] = (0, 0),
                 eye: int | None = None):
        super().__init__(gpu)
        _positive(width=width, height=height)
        if iterations < 0:
            raise InputError(f"must be >= 0, got {iterations}", field="iterations")
        self.width, self.height, self.iterations = width, height, iterations
        self.target = RenderTarget(gpu, width, height, depth=False)
        self.work = FragmentLoopTile(gpu, [self.target], frame or (width, height),
                                     (*offset, width, height), offset, iterations, eye)
        self._owned.append(self.work)
        self.bytes = width * height * 4


class Mesh(_GraphicsPass):
    """T triangles of a mesh (`shape`: our torus, or vmgpu's sphere as vmgpu draws it; `cull`:
    none or back faces) into colour RGBA8 + depth D16 (`first`..: a share), as the runner's
    sort-last share; `eye` 0 / 1 renders one view of the stereo camera (XR); `rect` (x, y, w,
    h) renders only those pixels of the frame, into a target of their size (an XR half-eye
    view, a sort-first strip)."""

    def __init__(self, gpu: "Gpu", width: int, height: int, triangles: int, *,
                 first: int = 0, count: int | None = None, eye: int | None = None,
                 rect: tuple[int, int, int, int] | None = None, shape: str = "torus",
                 cull: str = "none"):
        super().__init__(gpu)
        _positive(width=width, height=height, triangles=triangles)
        check_mesh_options(shape, cull)
        self.width, self.height, self.triangles = width, height, triangles
        self.first, self.count = first, (triangles - first if count is None else count)
        rect = rect or (0, 0, width, height)
        self.target = RenderTarget(gpu, rect[2], rect[3], depth=True)
        self.work = MeshShare(gpu, [self.target], (width, height), triangles, self.first,
                              self.count, eye=eye, rect=rect, origin=(rect[0], rect[1]),
                              shape=shape, cull=cull)
        self._owned.append(self.work)
        self.bytes = rect[2] * rect[3] * 6


class _Composite(_GraphicsPass):
    """The runner's composite: each input drawn into its rectangle of a frame it *loads*. The
    frame is cleared once here, as the primary's own render clears it every frame."""

    def __init__(self, gpu: "Gpu", width: int, height: int, inputs: list[tuple[Image, Image | None]],
                 rects: list[tuple[int, int, int, int]], depth: bool):
        super().__init__(gpu)
        self.width, self.height = width, height
        self.target = RenderTarget(gpu, width, height, depth=depth, clear=False)
        images = [i for i in (self.target.color, self.target.depth) if i is not None]
        gpu.run("graphics", lambda cmd: clear_images(cmd, images))
        self.work = CompositeInto(gpu, self.target, (width, height), [inputs], rects, depth)
        self._owned.append(self.work)
        self.bytes = width * height * (6 if depth else 4)


class CompositeSortFirst(_Composite):
    """One rectangle per contribution, sampling its colour tile into its rows of the frame.
    `textures[i]` is a (width x rows_i) RGBA8 image; give your own or let the pass create them."""

    def __init__(self, gpu: "Gpu", width: int, height: int, inputs: int, *,
                 textures: Sequence[Image] | None = None):
        _positive(width=width, height=height, inputs=inputs)
        tiles = tile_rows(height, inputs)
        made = textures is None
        images = [gpu.image(width, rows) for _, rows in tiles] if made else list(textures or ())
        super().__init__(gpu, width, height, [(img, None) for img in images],
                         [(0, y0, width, rows) for y0, rows in tiles], depth=False)
        self.tiles, self.inputs = tiles, images
        if made:
            self._owned[:0] = images


class CompositeSortLast(_Composite):
    """A full-screen quad per contribution writing its colour and depth; the depth test keeps
    the nearest fragment."""

    def __init__(self, gpu: "Gpu", width: int, height: int, inputs: int, *,
                 textures: Sequence[tuple[Image, Image]] | None = None):
        _positive(width=width, height=height, inputs=inputs)
        made = textures is None
        pairs = ([(gpu.image(width, height), gpu.image(width, height, DEPTH_FORMAT)) for _ in range(inputs)]
                 if made else list(textures or ()))
        super().__init__(gpu, width, height, list(pairs), [(0, 0, width, height)] * inputs, depth=True)
        self.inputs = pairs
        if made:
            self._owned[:0] = [img for pair in pairs for img in pair]


class Present(_GraphicsPass):
    """Present as the runner does it: a whole-image copy of the RGBA8 frame into the displayed
    image (both in GENERAL layout)."""

    def __init__(self, gpu: "Gpu", width: int, height: int):
        super().__init__(gpu)
        _positive(width=width, height=height)
        self.width, self.height = width, height
        self.frame, self.display = gpu.image(width, height), gpu.image(width, height)
        self._owned += [self.frame, self.display]
        self.bytes = width * height * 4

    def record(self, cmd: Any) -> None:
        copy_image(cmd, self.frame, self.display)


class FilterPass(_GraphicsPass):
    """The runner's filter (a fragment loop sampling `inputs` images at its pixel): the
    pipelining chain's consumer passes and, with 2 inputs, the temporal pass (current frame +
    history). The inputs are images of its own, filled with a gradient once."""

    def __init__(self, gpu: "Gpu", width: int, height: int, iterations: int, inputs: int):
        super().__init__(gpu)
        _positive(width=width, height=height, inputs=inputs)
        if iterations < 0:
            raise InputError(f"must be >= 0, got {iterations}", field="iterations")
        self.width, self.height, self.iterations = width, height, iterations
        self.inputs = [gpu.image(width, height) for _ in range(inputs)]
        self._owned += self.inputs
        ramp = (np.arange(width * height * 4, dtype=np.uint32) % 251).astype(np.uint8)
        for img in self.inputs:
            upload(gpu, img, ramp)
        self.target = RenderTarget(gpu, width, height, depth=False)
        self.work = Filter(gpu, [self.target], (width, height), iterations,
                           [[img] for img in self.inputs])
        self._owned.append(self.work)
        self.bytes = width * height * 4


class ParticleRender(_GraphicsPass):
    """Draw P billboards (6 vertices each, built by ParticleUpdate) additively into RGBA8, as
    the runner's particle draw."""

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
        self.work = ParticleDraw(gpu, [self.target], particles)
        self._owned.append(self.work)
        self.bytes = width * height * 4

    def record(self, cmd: Any) -> None:
        self.work.record(cmd, 0, self.vertices)
