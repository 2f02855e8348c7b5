"""The passes themselves: what the runner executes and the microbenchmarks time.

Each renders into targets it is given (`record(cmd, slot)` picks one of B buffered targets):
a primary renders its tile straight into the frame it composites into, and compositing loads
the frame instead of clearing it. :mod:`.standalone` wraps each with images of its own for
`mgpusim measure`. Render passes that differ only in load/store ops are compatible, so one
pipeline serves the clearing and the loading target alike.

Sort-first tiles are exact: a tile is rendered with the *full-frame* viewport shifted by the
tile's origin and a scissor on the tile, so every fragment sees the same rasterizer inputs as
in a single-GPU render of the whole frame.
"""
from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Any, Sequence, cast

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.model.geometry import PASS_OPTIONS
from mgpusim.real.passes.draw import (
    draw_indexed,
    draw_vertices,
    quad_pc,
    sphere_geometry,
    sphere_matrices,
    stages,
    torus_mesh,
    view_matrix,
)
from mgpusim.real.vulkan.buffers import Image
from mgpusim.real.vulkan.copies import upload
from mgpusim.real.vulkan.pipelines import Pipeline, RenderTarget, graphics_pipeline
from mgpusim.real.vulkan.vk_errors import vk

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu

Rect = tuple[int, int, int, int]  # x, y, width, height


def target_over(gpu: "Gpu", color: Image, depth: Image | None, clear: bool) -> RenderTarget:
    """A render target over existing images (never destroys them)."""
    return RenderTarget(gpu, color.width, color.height, depth=depth is not None, clear=clear,
                        color=color, depth_image=depth)


def begin(target: RenderTarget, cmd: Any, area: Rect, viewport: Rect) -> None:
    """Begin `target`'s render pass on `area` (scissor too) with `viewport` (may lie partly
    outside the target: a tile's view of the whole frame)."""
    v = vk()
    clears = [v.VkClearValue(color=v.VkClearColorValue(float32=[0.0, 0.0, 0.0, 0.0]))]
    if target.depth is not None:
        clears.append(v.VkClearValue(depthStencil=v.VkClearDepthStencilValue(depth=1.0, stencil=0)))
    rect = v.VkRect2D(offset=v.VkOffset2D(x=area[0], y=area[1]),
                      extent=v.VkExtent2D(width=area[2], height=area[3]))
    info = v.VkRenderPassBeginInfo(renderPass=target.render_pass, framebuffer=target.framebuffer,
                                   renderArea=rect, clearValueCount=len(clears), pClearValues=clears)
    v.vkCmdBeginRenderPass(cmd, info, v.VK_SUBPASS_CONTENTS_INLINE)
    viewports = [v.VkViewport(x=viewport[0], y=viewport[1], width=viewport[2],
                              height=viewport[3], minDepth=0.0, maxDepth=1.0)]
    scissors = [rect]
    v.vkCmdSetViewport(cmd, 0, 1, viewports)
    v.vkCmdSetScissor(cmd, 0, 1, scissors)


def _local(rect: Rect, origin: tuple[int, int]) -> Rect:
    """Frame rectangle `rect` in the pixels of a target whose pixel (0, 0) is frame `origin`."""
    return (rect[0] - origin[0], rect[1] - origin[1], rect[2], rect[3])


def _placement(frame: tuple[int, int], rect: Rect | None,
               origin: tuple[int, int]) -> tuple[Rect, Rect, bool]:
    """(area, viewport, empty) of a pass drawing frame rectangle `rect` (None: the whole frame)
    into a target whose pixel (0, 0) is frame `origin`: the target's area it draws (render area
    and scissor), the full-frame viewport shifted by the origin (what makes a tile exact), and
    whether there is nothing to draw. Shared so that every tiled pass places itself alike."""
    rect = rect or (0, 0, frame[0], frame[1])
    viewport = (-origin[0], -origin[1], frame[0], frame[1])
    return _local(rect, origin), viewport, rect[2] * rect[3] == 0


class _FramePass:
    """Common part: per-slot targets, one pipeline, owned objects destroyed in reverse."""

    def __init__(self, gpu: "Gpu", targets: Sequence[RenderTarget]):
        if not targets:
            raise InputError("a pass needs at least one target")
        self.gpu, self.targets = gpu, list(targets)
        self._owned: list[Any] = list(self.targets)

    def destroy(self) -> None:
        for obj in reversed(self._owned):
            obj.destroy()
        self._owned.clear()


#: A stereo pair's texture-coordinate shift of the right eye in the fragment loop (the left
#: eye and a mono frame are unshifted), so that the two eyes' pictures differ.
EYE_UV_SHIFT = 0.25


class FragmentLoopTile(_FramePass):
    """The fragment-loop benchmark on the frame rectangle `rect`, into targets whose pixel (0, 0)
    is frame pixel `origin`; `eye` 1 shifts the texture coordinates (a stereo view)."""

    def __init__(self, gpu: "Gpu", targets: Sequence[RenderTarget], frame: tuple[int, int],
                 rect: Rect, origin: tuple[int, int], iterations: int, eye: int | None = None):
        super().__init__(gpu, targets)
        self.pipeline: Pipeline = graphics_pipeline(gpu, self.targets[0], "quad.vert", "loop.frag")
        self._owned.append(self.pipeline)
        self.area, self.viewport, self.empty = _placement(frame, rect, origin)
        shift = EYE_UV_SHIFT if eye == 1 else 0.0
        self._pc = quad_pc((-1, -1, 1, 1), (shift, 0, 1 + shift, 1), (iterations, 0, 0, 0))

    def record(self, cmd: Any, slot: int = 0) -> None:
        if self.empty:
            return
        v = vk()
        begin(self.targets[slot], cmd, self.area, self.viewport)
        self.pipeline.bind(cmd)
        self.pipeline.push(cmd, stages(), self._pc)
        v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


def check_mesh_options(shape: str, cull: str) -> None:
    """Refuse a mesh the runner cannot draw, before anything is allocated for it."""
    for key, value in (("shape", shape), ("cull", cull)):
        if value not in PASS_OPTIONS["mesh"][key]:
            raise InputError(f"the runner draws a mesh of {key} {' or '.join(PASS_OPTIONS['mesh'][key])}, "
                             f"not {value!r}", field=key)


class MeshShare(_FramePass):
    """Triangles [first, first + count) of a mesh of `triangles` triangles, drawn with depth:
    sort-last's geometry share (only the share is drawn). `shape` picks the mesh and its camera
    (`torus`: our generated torus, one interleaved vertex buffer, not indexed; `sphere`: the
    sphere the vmgpu tool writes, drawn as vmgpu draws it, see :func:`sphere_geometry`), `cull`
    what the pipeline culls (`none`, `back`). `rect` (default: the whole frame) is the part of
    the frame rendered, into targets whose pixel (0, 0) is frame pixel `origin` (exact, as the
    fragment loop's tiles); `eye` 0 / 1 picks a stereo camera."""

    def __init__(self, gpu: "Gpu", targets: Sequence[RenderTarget], frame: tuple[int, int],
                 triangles: int, first: int, count: int, *, rect: Rect | None = None,
                 origin: tuple[int, int] = (0, 0), eye: int | None = None,
                 shape: str = "torus", cull: str = "none"):
        super().__init__(gpu, targets)
        if self.targets[0].depth is None:
            raise InputError("a mesh pass needs a target with depth", field="depth")
        check_mesh_options(shape, cull)
        self.count, self.frame, self.shape = count, frame, shape
        self.area, self.viewport, _ = _placement(frame, rect, origin)  # clears even if empty
        self.buffers: list[Any] = []
        if count > 0:
            self._upload(gpu, triangles, first, count)
        attributes = [(0, "R32G32B32_SFLOAT", 0), (1, "R32G32B32_SFLOAT", 12 if shape == "torus" else 0)]
        self.pipeline = graphics_pipeline(
            gpu, self.targets[0], "mesh.vert" if shape == "torus" else "sphere.vert",
            "mesh.frag" if shape == "torus" else "sphere.frag", push_size=64 if shape == "torus" else 128,
            vertex_attributes=attributes, stride=24, strides=(12, 12) if shape == "sphere" else (),
            depth_test=True, cull_back=cull == "back")
        self._owned.append(self.pipeline)
        self._push = view_matrix(eye) if shape == "torus" else sphere_matrices(frame, eye)

    def _upload(self, gpu: "Gpu", triangles: int, first: int, count: int) -> None:
        """The share's geometry in device-local buffers: the torus's vertices, or the sphere's
        positions, normals and indices."""
        if self.shape == "torus":
            arrays = [torus_mesh(triangles)[3 * first:3 * (first + count)]]
        else:
            arrays = list(sphere_geometry(triangles, first, count))
        v = vk()
        indices = v.VK_BUFFER_USAGE_INDEX_BUFFER_BIT | v.VK_BUFFER_USAGE_TRANSFER_DST_BIT
        for data in arrays:  # the indices last, 32-bit
            buffer = gpu.buffer(data.nbytes, host_visible=False,
                                usage=indices if data.dtype == np.uint32 else None)
            self._owned.insert(0, buffer)
            upload(gpu, buffer, data)
            self.buffers.append(buffer)

    def record(self, cmd: Any, slot: int = 0) -> None:
        v = vk()
        begin(self.targets[slot], cmd, self.area, self.viewport)  # clears even an empty share
        if self.buffers and self.shape == "torus":
            draw_vertices(cmd, self.pipeline, self._push, self.buffers[0], 3 * self.count)
        elif self.buffers:
            draw_indexed(cmd, self.pipeline, self._push, self.buffers[:2], self.buffers[2], 3 * self.count)
        v.vkCmdEndRenderPass(cmd)


class CompositeInto(_FramePass):
    """Draws each input (colour, or colour + depth with the depth test) into its frame
    rectangle of a *loading* target; `inputs[slot][k]` is input k's images in buffer `slot`.
    `target` may be several buffered copies of the frame (a list): `record(cmd, slot,
    target_slot)` draws into copy `target_slot`."""

    def __init__(self, gpu: "Gpu", target: RenderTarget | Sequence[RenderTarget],
                 frame: tuple[int, int], inputs: Sequence[Sequence[tuple[Image, Image | None]]],
                 rects: Sequence[Rect], depth: bool):
        super().__init__(gpu, [target] if isinstance(target, RenderTarget) else target)
        target = self.targets[0]
        if any(t.clear for t in self.targets):
            raise InputError("the composite must load the frame, not clear it")
        self.frame = frame
        slots, k = len(inputs), len(rects)
        frag, samplers = ("sample_depth.frag", 2) if depth else ("sample.frag", 1)
        self.pipeline = graphics_pipeline(gpu, target, "quad.vert", frag, samplers=samplers,
                                          depth_test=depth, max_sets=max(1, slots * k))
        self._owned.append(self.pipeline)
        # with `depth` every input has its depth image
        self.sets = [[self.pipeline.descriptor_set([c, cast(Image, d)] if depth else [c]) for c, d in per_slot]
                     for per_slot in inputs]
        w, h = frame
        self._pcs = [quad_pc((-1 + 2 * x / w, -1 + 2 * y / h, -1 + 2 * (x + rw) / w,
                               -1 + 2 * (y + rh) / h), (0, 0, 1, 1))
                     for x, y, rw, rh in rects]
        self._nonempty = [r[2] * r[3] > 0 for r in rects]

    def record(self, cmd: Any, slot: int = 0, target_slot: int = 0) -> None:
        v = vk()
        full = (0, 0, self.frame[0], self.frame[1])
        begin(self.targets[target_slot], cmd, full, full)
        for dset, pc, live in zip(self.sets[slot], self._pcs, self._nonempty):
            if live:
                self.pipeline.bind(cmd, dset)
                self.pipeline.push(cmd, stages(), pc)
                v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


class Filter(_FramePass):
    """A fragment loop that samples `len(inputs)` (1..4) images at its own pixel and combines
    them (shaders/filter.frag): the pipelining chain's passes that read other passes' outputs,
    and the temporal pass, whose last input is the previous frame's result. Like a fragment-loop
    tile it draws the frame rectangle `rect` (default: the whole frame) into targets whose pixel
    (0, 0) is frame pixel `origin`; its inputs share that origin (a tile's images), so the
    filter of a tile is exact. `inputs[k][b]` is buffered copy b of input k; `record(cmd,
    slot, input_slots)` samples copy `input_slots[k]` of each."""

    MAX_INPUTS = 4

    def __init__(self, gpu: "Gpu", targets: Sequence[RenderTarget], frame: tuple[int, int],
                 iterations: int, inputs: Sequence[Sequence[Image]], *, rect: Rect | None = None,
                 origin: tuple[int, int] = (0, 0)):
        super().__init__(gpu, targets)
        if not 1 <= len(inputs) <= self.MAX_INPUTS:
            raise InputError(f"a filter samples 1 to {self.MAX_INPUTS} inputs, got {len(inputs)}",
                             field="inputs")
        self.area, self.viewport, self.empty = _placement(frame, rect, origin)
        x, y, w, h = self.area
        for k, copies in enumerate(inputs):
            if not self.empty and any(img.width < x + w or img.height < y + h for img in copies):
                raise InputError(f"filter input {k} does not cover the {w}x{h} pixels at "
                                 f"({x}, {y}) that the filter draws", field="inputs")
        combos = list(itertools.product(*(range(len(c)) for c in inputs)))
        self.pipeline = graphics_pipeline(gpu, self.targets[0], "quad.vert", "filter.frag",
                                          samplers=self.MAX_INPUTS, max_sets=len(combos))
        self._owned.append(self.pipeline)
        pad = self.MAX_INPUTS - len(inputs)
        self.sets = {combo: self.pipeline.descriptor_set(
            [inputs[k][b] for k, b in enumerate(combo)] + [inputs[0][combo[0]]] * pad)
            for combo in combos}
        self._pc = quad_pc((-1, -1, 1, 1), (0, 0, 1, 1), (iterations, len(inputs), 0, 0))

    def record(self, cmd: Any, slot: int = 0, input_slots: Sequence[int] | None = None) -> None:
        if self.empty:
            return
        v = vk()
        combo = tuple(input_slots) if input_slots is not None else (0,) * len(next(iter(self.sets)))
        begin(self.targets[slot], cmd, self.area, self.viewport)
        self.pipeline.bind(cmd, self.sets[combo])
        self.pipeline.push(cmd, stages(), self._pc)
        v.vkCmdDraw(cmd, 6, 1, 0, 0)
        v.vkCmdEndRenderPass(cmd)


class ParticleDraw(_FramePass):
    """P additive billboards (6 vertices each, built by the particle update) drawn into a
    loading target: `record(cmd, slot, vertices)` draws the given vertex buffer."""

    def __init__(self, gpu: "Gpu", targets: Sequence[RenderTarget], particles: int):
        super().__init__(gpu, targets)
        self.particles = particles
        self.pipeline = graphics_pipeline(
            gpu, self.targets[0], "particle.vert", "particle.frag", push_size=64, stride=32,
            vertex_attributes=[(0, "R32G32B32A32_SFLOAT", 0), (1, "R32G32B32A32_SFLOAT", 16)],
            blend_add=True)
        self._owned.append(self.pipeline)
        self._mvp = view_matrix()

    def record(self, cmd: Any, slot: int, vertices: Any) -> None:
        """Draw `vertices` (None: no particles yet, the pass only loads or clears)."""
        target = self.targets[slot]
        full = (0, 0, target.width, target.height)
        begin(target, cmd, full, full)
        if vertices is not None:
            draw_vertices(cmd, self.pipeline, self._mvp, vertices, 6 * self.particles)
        vk().vkCmdEndRenderPass(cmd)


def copy_image(cmd: Any, src: Image, dst: Image) -> None:
    """Record a whole-image copy (present: frame -> displayed image)."""
    v = vk()
    layers = v.VkImageSubresourceLayers(aspectMask=src.aspect, mipLevel=0, baseArrayLayer=0,
                                        layerCount=1)
    zero = v.VkOffset3D(x=0, y=0, z=0)
    region = v.VkImageCopy(srcSubresource=layers, srcOffset=zero, dstSubresource=layers,
                           dstOffset=zero,
                           extent=v.VkExtent3D(width=src.width, height=src.height, depth=1))
    regions = [region]
    general = v.VK_IMAGE_LAYOUT_GENERAL
    v.vkCmdCopyImage(cmd, src.handle, general, dst.handle, general, 1, regions)
