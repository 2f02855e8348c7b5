"""Copies: recorders for image<->buffer and buffer<->buffer, upload/download helpers, and the
copy workloads that `mgpusim measure` times (copy_d2h, copy_h2d, copy_d2d).

Why recorders (functions of `cmd`): the runner composes them freely on any queue of a Gpu
(graphics or the dedicated transfer family) inside `Gpu.submit`, which adds the timestamps.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.real.vulkan.buffers import Buffer, Image
from mgpusim.real.vulkan.vk_errors import vk

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu


def copy_image_to_buffer(cmd: Any, image: Image, buffer: Buffer, offset: int = 0) -> None:
    """Record image -> buffer (tightly packed at `offset`)."""
    v = vk()
    regions = [image.region(offset)]
    v.vkCmdCopyImageToBuffer(cmd, image.handle, v.VK_IMAGE_LAYOUT_GENERAL, buffer.handle, 1,
                             regions)


def copy_buffer_to_image(cmd: Any, buffer: Buffer, image: Image, offset: int = 0) -> None:
    """Record buffer (tightly packed at `offset`) -> image."""
    v = vk()
    regions = [image.region(offset)]
    v.vkCmdCopyBufferToImage(cmd, buffer.handle, image.handle, v.VK_IMAGE_LAYOUT_GENERAL, 1,
                             regions)


def copy_buffer(cmd: Any, src: Buffer, dst: Buffer, size: int | None = None,
                src_offset: int = 0, dst_offset: int = 0) -> None:
    """Record buffer -> buffer of `size` bytes (default: all of the smaller one)."""
    v = vk()
    size = min(src.size - src_offset, dst.size - dst_offset) if size is None else size
    region = v.VkBufferCopy(srcOffset=src_offset, dstOffset=dst_offset, size=size)
    regions = [region]
    v.vkCmdCopyBuffer(cmd, src.handle, dst.handle, 1, regions)


def _layers(image: Image) -> Any:
    v = vk()
    return v.VkImageSubresourceLayers(aspectMask=image.aspect, mipLevel=0, baseArrayLayer=0,
                                      layerCount=1)


def _buffer_region(image: Image, offset: int, x: int, y: int, width: int, height: int) -> Any:
    v = vk()
    return v.VkBufferImageCopy(bufferOffset=offset, bufferRowLength=0, bufferImageHeight=0,
                               imageSubresource=_layers(image),
                               imageOffset=v.VkOffset3D(x=x, y=y, z=0),
                               imageExtent=v.VkExtent3D(width=width, height=height, depth=1))


def copy_rect_to_buffer(cmd: Any, image: Image, buffer: Buffer, offset: int,
                        rect: tuple[int, int, int, int]) -> None:
    """Record the (x, y, width, height) rectangle of `image` -> buffer (tightly packed)."""
    v = vk()
    regions = [_buffer_region(image, offset, *rect)]
    v.vkCmdCopyImageToBuffer(cmd, image.handle, v.VK_IMAGE_LAYOUT_GENERAL, buffer.handle, 1,
                             regions)


def copy_buffer_to_rect(cmd: Any, buffer: Buffer, offset: int, image: Image,
                        rect: tuple[int, int, int, int]) -> None:
    """Record buffer (tightly packed at `offset`) -> the (x, y, width, height) rectangle."""
    v = vk()
    regions = [_buffer_region(image, offset, *rect)]
    v.vkCmdCopyBufferToImage(cmd, buffer.handle, image.handle, v.VK_IMAGE_LAYOUT_GENERAL, 1,
                             regions)


def copy_rect(cmd: Any, src: Image, dst: Image, src_xy: tuple[int, int],
              dst_xy: tuple[int, int], size: tuple[int, int]) -> None:
    """Record an image -> image copy of a `size` rectangle (same format)."""
    v = vk()
    region = v.VkImageCopy(srcSubresource=_layers(src),
                           srcOffset=v.VkOffset3D(x=src_xy[0], y=src_xy[1], z=0),
                           dstSubresource=_layers(dst),
                           dstOffset=v.VkOffset3D(x=dst_xy[0], y=dst_xy[1], z=0),
                           extent=v.VkExtent3D(width=size[0], height=size[1], depth=1))
    regions = [region]
    general = v.VK_IMAGE_LAYOUT_GENERAL
    v.vkCmdCopyImage(cmd, src.handle, general, dst.handle, general, 1, regions)


def clear_image(cmd: Any, image: Image) -> None:
    """Record clearing a colour image to transparent black, or a depth image to 1."""
    v = vk()
    ranges = [image.range]
    general = v.VK_IMAGE_LAYOUT_GENERAL
    if image.aspect == v.VK_IMAGE_ASPECT_DEPTH_BIT:
        value = v.VkClearDepthStencilValue(depth=1.0, stencil=0)
        v.vkCmdClearDepthStencilImage(cmd, image.handle, general, value, 1, ranges)
    else:
        colour = v.VkClearColorValue(float32=[0.0, 0.0, 0.0, 0.0])
        v.vkCmdClearColorImage(cmd, image.handle, general, colour, 1, ranges)


def clear_images(cmd: Any, images: Iterable[Image]) -> None:
    """Record clearing each of `images` in turn (:func:`clear_image`)."""
    for image in images:
        clear_image(cmd, image)


def upload(gpu: "Gpu", target: Buffer | Image, data: np.ndarray) -> None:
    """Copy host `data` into a (device-local) buffer or image through a staging buffer."""
    raw = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    size = target.size if isinstance(target, Buffer) else target.bytes
    if raw.size != size:
        raise InputError(f"upload of {raw.size} bytes into a resource of {size} bytes")
    if isinstance(target, Buffer) and target.array is not None:
        target.array[:] = raw
        return
    staging = gpu.buffer(size, host_visible=True)
    try:
        assert staging.array is not None
        staging.array[:] = raw
        if isinstance(target, Buffer):
            gpu.run("graphics", lambda cmd: copy_buffer(cmd, staging, target))
        else:
            gpu.run("graphics", lambda cmd: copy_buffer_to_image(cmd, staging, target))
    finally:
        staging.destroy()


def download(gpu: "Gpu", source: Buffer | Image) -> np.ndarray:
    """The bytes of a buffer or image (uint8, a copy)."""
    if isinstance(source, Buffer) and source.array is not None:
        return source.array.copy()
    size = source.size if isinstance(source, Buffer) else source.bytes
    staging = gpu.buffer(size, host_visible=True)
    try:
        if isinstance(source, Buffer):
            gpu.run("graphics", lambda cmd: copy_buffer(cmd, source, staging))
        else:
            gpu.run("graphics", lambda cmd: copy_image_to_buffer(cmd, source, staging))
        assert staging.array is not None
        return staging.array.copy()
    finally:
        staging.destroy()


def image_shape_for(nbytes: int, max_width: int = 4096) -> tuple[int, int]:
    """An RGBA8 image (width, height) holding at least `nbytes` (width <= max_width)."""
    if nbytes <= 0:
        raise InputError(f"bytes must be positive, got {nbytes}", field="bytes")
    pixels = math.ceil(nbytes / 4)
    width = min(max_width, pixels)
    return width, math.ceil(pixels / width)


class _Copy:
    def __init__(self, gpu: "Gpu", queue: str):
        if queue not in ("graphics", "transfer"):
            raise InputError(f"queue must be graphics or transfer, got {queue!r}", field="queue")
        self.gpu, self.queue = gpu, queue
        self._resources: list[Buffer | Image] = []

    def destroy(self) -> None:
        for res in self._resources:
            res.destroy()


class CopyD2H(_Copy):
    """Device-local RGBA8 image -> host-visible buffer (a contribution read back)."""

    def __init__(self, gpu: "Gpu", bytes: int, queue: str = "graphics"):  # noqa: A002
        super().__init__(gpu, queue)
        self.image = gpu.image(*image_shape_for(bytes))
        self.buffer = gpu.buffer(self.image.bytes, host_visible=True)
        self._resources += [self.image, self.buffer]
        self.bytes = self.image.bytes

    def record(self, cmd: Any) -> None:
        copy_image_to_buffer(cmd, self.image, self.buffer)


class CopyH2D(_Copy):
    """Host-visible buffer -> device-local RGBA8 image (a contribution uploaded)."""

    def __init__(self, gpu: "Gpu", bytes: int, queue: str = "graphics"):  # noqa: A002
        super().__init__(gpu, queue)
        self.image = gpu.image(*image_shape_for(bytes))
        self.buffer = gpu.buffer(self.image.bytes, host_visible=True)
        assert self.buffer.array is not None
        self.buffer.array[:] = 0x5A
        self._resources += [self.image, self.buffer]
        self.bytes = self.image.bytes

    def record(self, cmd: Any) -> None:
        copy_buffer_to_image(cmd, self.buffer, self.image)


class CopyD2D(_Copy):
    """Device-local buffer -> device-local buffer."""

    def __init__(self, gpu: "Gpu", bytes: int, queue: str = "graphics"):  # noqa: A002
        super().__init__(gpu, queue)
        if bytes <= 0:
            raise InputError(f"bytes must be positive, got {bytes}", field="bytes")
        self.src = gpu.buffer(bytes, host_visible=False)
        self.dst = gpu.buffer(bytes, host_visible=False)
        self._resources += [self.src, self.dst]
        self.bytes = int(bytes)

    def record(self, cmd: Any) -> None:
        copy_buffer(cmd, self.src, self.dst)
